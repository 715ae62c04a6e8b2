"""pe_mjx/reproduce.py (`pe-mjx reproduce`) end to end at a tiny budget: trains, evaluates, writes
the report, and resumes without redoing anything; and what train/launch.py did (--only,
--env-steps, --stop-after, --train-seed, --skip-eval)."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = [str(Path(sys.executable).parent / "pe-mjx"), "reproduce"]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*SCRIPT, *args], capture_output=True, text=True, timeout=1200)


def test_tiny_table_ii_and_resume(tmp_path):
    args = [
        "--fraction", "0.00002",  # 200 env steps: one iteration per co-evolution
        "--encoders", "mix", "mean",
        "--tables", "II",
        "--trials", "2",
        "--backend", "kinematic",
        "--runs", str(tmp_path / "runs"),
        "--out", str(tmp_path / "results"),
        "--docs", str(tmp_path / "results.md"),
    ]  # fmt: skip
    first = _run(*args)
    assert first.returncode == 0, first.stderr[-3000:]
    # Only the scale Table II uses is trained.
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["mean-16-4-4", "mix-16-4-4"]
    report = (tmp_path / "results.md").read_text()
    assert "## Table II: scene 16-4-4" in report
    rows = [line for line in report.splitlines() if line.startswith("| E_")]
    # Pairings of one co-evolution with itself are left out, as in the paper.
    assert len(rows) == 2
    # Each cell is ours / the paper's (Table II: E_MIX vs P_MEAN success 0.503, E_MEAN vs P_MIX
    # 0.748).
    mix_vs_mean = next(r for r in rows if r.startswith("| E_MIX(16,4,4) | P_MEAN(16,4,4)"))
    assert mix_vs_mean.split("|")[3].strip().endswith("/ 0.503")
    mean_vs_mix = next(r for r in rows if r.startswith("| E_MEAN(16,4,4) | P_MIX(16,4,4)"))
    assert mean_vs_mix.split("|")[3].strip().endswith("/ 0.748")
    assert (tmp_path / "results" / "table-II" / "results.json").exists()

    again = _run(*args)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "training" not in again.stdout and "pursuit x" not in again.stdout
    assert (tmp_path / "results.md").read_text() == report


def test_unknown_table_is_an_error(tmp_path):
    out = _run("--tables", "IX", "--skip-train", "--runs", str(tmp_path))
    assert out.returncode == 2
    assert out.stderr.startswith("pe-mjx: error:") and "IX" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1


def test_transferred_evaders_are_stated_in_the_report(tmp_path):
    from pe_mjx.reproduce import ReproduceArgs, _report, table_scales

    assert table_scales("V") == ("16-4-4", "20-5-8", "16-4-4")
    assert table_scales("V", "pursuers") == ("16-4-4", "20-5-8", "20-5-8")
    assert table_scales("III", "pursuers") == ("20-5-8", "20-5-8", "20-5-8")
    args = ReproduceArgs(tables=("III", "VI"), transfer_evaders="pursuers", docs=tmp_path / "t.md")
    report = _report(args, {"III": {"pairings": []}, "VI": {"pairings": []}})
    assert "## Table VI: scene 24-6-12 (pursuers trained at 20-5-8, evaders at 20-5-8)" in report
    vi = report.split("## Table VI")[1]
    assert "The evaders were trained at 20-5-8, not at 24-6-12" in vi
    assert "The evaders were trained" not in report.split("## Table VI")[0]

    # A baseline row (the paper has no such cell) shows "-" beside ours; a cross row the paper's.
    summary = {"success_rate": 0.5, "travel_distance": 9.0, "pursuit_cost": 5.0}
    summary["per_evader_cost"] = 1.25

    def pairing(evader, pursuer, e_label, p_label):
        return {
            "evader": {"source": evader, "label": e_label},
            "pursuer": {"source": pursuer, "label": p_label},
            "summary": summary,
        }

    data = {
        "pairings": [
            pairing("scripted", "assets/policies/mix-20-5-8", "E_scripted", "P_MIX(20,5,8)"),
            pairing("p/mean-20-5-8", "p/mix-20-5-8", "E_MEAN(20,5,8)", "P_MIX(20,5,8)"),
        ]
    }
    report = _report(dataclasses.replace(args, baselines=("III",)), {"III": data})
    rows = [line for line in report.splitlines() if line.startswith("| E_")]
    assert rows[0] == "| E_scripted | P_MIX(20,5,8) | 0.500 / - | 9.00 / - | 5.00 / - | 1.250 / - |"
    assert rows[1].split("|")[3].strip() == "0.500 / 0.932"


def test_suffix_picks_the_runs_with_it_and_names_them_in_the_report(tmp_path):
    from pe_mjx.reproduce import ReproduceArgs, _report, found_runs

    policies = ROOT / "pe_mjx" / "assets" / "policies"
    shutil.copytree(policies / "mix-20-5-8", tmp_path / "mix-20-5-8-3m")
    shutil.copytree(policies / "mean-20-5-8-3m", tmp_path / "mean-20-5-8")
    args = ReproduceArgs(runs=tmp_path, encoders=("mix", "mean"), suffix="-3m")
    assert found_runs(args, "20-5-8") == [str(tmp_path / "mix-20-5-8-3m")]
    plain = dataclasses.replace(args, suffix="")
    assert found_runs(plain, "20-5-8") == [str(tmp_path / "mean-20-5-8")]
    assert found_runs(args, "16-4-4") == []
    report = _report(dataclasses.replace(args, tables=("III",)), {"III": {"pairings": []}})
    assert "evaders at 20-5-8; runs `<encoder>-<scale>-3m`)" in report


def test_a_suffix_with_a_path_in_it_is_one_line_error(tmp_path):
    out = _run("--suffix", "/../x", "--skip-train", "--runs", str(tmp_path), "--out", str(tmp_path))
    assert out.returncode != 0
    assert out.stderr.startswith("pe-mjx: error:") and "--suffix" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_a_kept_table_names_the_runs_it_does_not_play(tmp_path, capsys):
    # A table whose results.json exists is kept; a run found since (a method added) is named,
    # with how to play it, instead of the table going silently stale.
    import json

    from pe_mjx.reproduce import ReproduceArgs, _evaluate

    policies = ROOT / "pe_mjx" / "assets" / "policies"
    for name, shipped in (("mix-20-5-8", "mix-20-5-8"), ("mean-20-5-8", "mean-20-5-8-3m")):
        shutil.copytree(policies / shipped, tmp_path / "runs" / name)
    mix = str(tmp_path / "runs" / "mix-20-5-8")
    table = tmp_path / "out" / "table-III"
    table.mkdir(parents=True)
    kept = {"pairings": [{"pursuer": {"source": mix}, "evader": {"source": "scripted"}}]}
    (table / "results.json").write_text(json.dumps(kept))
    args = ReproduceArgs(
        runs=tmp_path / "runs", out=tmp_path / "out", encoders=("mix", "mean"), tables=("III",)
    )
    assert _evaluate(args) == {"III": kept}
    said = capsys.readouterr().out
    assert f"does not play {tmp_path / 'runs' / 'mean-20-5-8'}; add --extend" in said
    assert f"(or delete {table})" in said
    assert mix + "," not in said
    # Once every run it finds is in the table, nothing is said.
    mean = str(tmp_path / "runs" / "mean-20-5-8")
    kept["pairings"].append({"pursuer": {"source": "scripted"}, "evader": {"source": mean}})
    (table / "results.json").write_text(json.dumps(kept))
    _evaluate(args)
    assert "does not play" not in capsys.readouterr().out


def test_extend_plays_a_kept_table_again_keeping_what_it_can(tmp_path, monkeypatch, capsys):
    # With --extend a table that lacks runs found since is handed back to the evaluation with
    # itself as the earlier evaluation to keep pairings from (tests/test_evaluate.py checks
    # what is kept); the table is otherwise played as a new one would be.
    import json

    from pe_mjx import evaluate as ev
    from pe_mjx.reproduce import ReproduceArgs, _evaluate

    policies = ROOT / "pe_mjx" / "assets" / "policies"
    for name, shipped in (("mix-20-5-8", "mix-20-5-8"), ("mean-20-5-8", "mean-20-5-8-3m")):
        shutil.copytree(policies / shipped, tmp_path / "runs" / name)
    mix, mean = (str(tmp_path / "runs" / n) for n in ("mix-20-5-8", "mean-20-5-8"))
    table = tmp_path / "out" / "table-III"
    table.mkdir(parents=True)
    kept = {"pairings": [{"pursuer": {"source": mix}, "evader": {"source": "scripted"}}]}
    (table / "results.json").write_text(json.dumps(kept))
    calls = []

    def evaluate(pursuers, evaders, scene, out, *args, **kwargs):
        calls.append((pursuers, evaders, scene, out, kwargs))
        extended = {
            "pairings": [
                {"pursuer": {"source": p}, "evader": {"source": e}}
                for p in pursuers
                for e in evaders
            ]
        }
        (out / "results.json").write_text(json.dumps(extended))

    monkeypatch.setattr(ev, "evaluate", evaluate)
    args = ReproduceArgs(
        runs=tmp_path / "runs",
        out=tmp_path / "out",
        encoders=("mix", "mean"),
        tables=("III",),
        extend=True,
    )
    done = _evaluate(args)
    assert f"table III: extending {table / 'results.json'} with {mean}" in capsys.readouterr().out
    [(pursuers, evaders, scene, out, kwargs)] = calls
    assert (pursuers, evaders, scene, out) == ([mix, mean], [mix, mean], "20-5-8", table)
    assert kwargs["keep"] == table and kwargs["skip_same_method"] and kwargs["progress"]
    assert len(done["III"]["pairings"]) == 4
    # Complete now: kept as it is, nothing played.
    _evaluate(args)
    assert len(calls) == 1


def test_what_train_launch_did_is_reproduce_only_stop_after_and_skip_eval(tmp_path, monkeypatch):
    """--only picks runs by name (not by table), --env-steps sets their budget, --stop-after and
    --train-seed reach `train`, a run with a checkpoint is resumed (and one at its budget left
    alone), --no-progress reaches it too, and nothing is evaluated while a run is unfinished or with
    --skip-eval."""
    import pe_mjx.ppo.run
    from pe_mjx.policy import store
    from pe_mjx.reproduce import ReproduceArgs, reproduce

    calls = []

    class State:
        env_steps = 100  # below the budget: unfinished

    def train(config, out, resume=False, stop_after=None, progress=True):
        calls.append((out.name, config.env_steps, config.seed, resume, stop_after, progress))
        return None, State()

    monkeypatch.setattr(pe_mjx.ppo.run, "train", train)
    done_meta = {"env_steps": 5000}
    (tmp_path / "mean-20-5-8" / store.CHECKPOINT_DIR).mkdir(parents=True)
    (tmp_path / "mix-16-4-4" / store.CHECKPOINT_DIR).mkdir(parents=True)
    monkeypatch.setattr(
        store, "read_meta", lambda run: done_meta if "16-4-4" in str(run) else {"env_steps": 0}
    )
    args = ReproduceArgs(
        runs=tmp_path,
        only=("mix-20-5-8", "mean-20-5-8", "mix-16-4-4"),
        env_steps=5000,
        stop_after=3,
        train_seed=7,
        progress=False,
        docs=tmp_path / "report.md",
        out=tmp_path / "results",
    )
    assert reproduce(args) is None  # unfinished: no table, no report
    assert sorted(calls) == [
        ("mean-20-5-8", 5000, 7, True, 3, False),
        ("mix-20-5-8", 5000, 7, False, 3, False),
    ]
    assert not (tmp_path / "report.md").exists() and not (tmp_path / "results").exists()


def test_reproduce_flags_are_checked_by_the_args_themselves(tmp_path, capsys):
    import pytest

    from pe_mjx.cli import main

    for flags, message in (
        (("--only", "mix-9-9-9"), "--only: unknown runs mix-9-9-9"),
        (("--env-steps", "0"), "--env-steps must be >= 1"),
        (("--stop-after", "0"), "--stop-after must be >= 1"),
        (("--fraction", "2"), "--fraction must be in (0, 1]"),
    ):
        with pytest.raises(SystemExit) as exit_:
            main(["reproduce", *flags, "--runs", str(tmp_path), "--out", str(tmp_path / "o")])
        assert exit_.value.code == 2, flags
        err = capsys.readouterr().err
        assert err.startswith(f"pe-mjx: error: {message}") and len(err.splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []
