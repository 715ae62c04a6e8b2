"""The leaderboard (`pe_mjx.ratings.board`) and `pe-mjx rate`, which writes it: its files, its
refusal to overwrite, its one-line errors for every kind of bad input, the installed console
script, and the committed leaderboards."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from pe_mjx import ratings

ROOT = Path(__file__).resolve().parents[2]
TABLE_III = ROOT / "docs/data/paper-3m/table-III/results.json"
SCENE_240 = ROOT / "docs/data/transfer-240-60-120/results.json"
LEADERBOARDS = ROOT / "docs/data/leaderboards"


def _write(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


def _small(data: dict) -> dict:
    """The committed Table III cut to the 3M MIX and the scripted teams (4 pairings)."""
    keep = ("assets/policies/mix-20-5-8-3m", "scripted")
    small = copy.deepcopy(data)
    small["pairings"] = [
        p for p in small["pairings"] if {p["pursuer"]["source"], p["evader"]["source"]} <= set(keep)
    ]
    small["meta"]["pursuers"] = small["meta"]["evaders"] = list(keep)
    return small


def test_pe_mjx_rate_writes_the_leaderboard_and_refuses_to_overwrite(tmp_path, capsys):
    from pe_mjx.cli import main

    out = tmp_path / "board"
    main(["rate", str(TABLE_III), "--out", str(out), "--resamples", "50"])
    said = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["leaderboard.json", "leaderboard.md"]
    board = json.loads((out / "leaderboard.json").read_text())
    assert (board["scene"], board["backend"], board["model"]["resamples"]) == (
        "20-5-8",
        "kinematic",
        50,
    )
    names = {team: [r["name"] for r in board[team]] for team in ("pursuers", "evaders")}
    methods = {"birnn-20-5-8-3m", "mean-20-5-8-3m", "mix-20-5-8-3m", "mlp-20-5-8-3m", "scripted"}
    assert set(names["pursuers"]) == set(names["evaders"]) == methods
    assert [r["rank"] for r in board["pursuers"]] == [1, 2, 3, 4, 5]
    values = [r["rating"] for r in board["pursuers"]]
    assert values == sorted(values, reverse=True)
    anchor = next(r for r in board["evaders"] if r["name"] == "scripted")
    assert anchor["rating"] == 0.0 and anchor["matches"] == 5 * 100 * 5
    assert (out / "leaderboard.md").read_text() in said
    assert "| 1 | `" in said and f"wrote {out / 'leaderboard.md'}" in said

    with pytest.raises(SystemExit) as exit_:
        main(["rate", str(TABLE_III), "--out", str(out)])
    assert exit_.value.code == 2 and "exists; pass --force" in capsys.readouterr().err
    main(["rate", str(TABLE_III), "--out", str(out), "--resamples", "20", "--force"])
    assert json.loads((out / "leaderboard.json").read_text())["model"]["resamples"] == 20


def _bad_inputs(tmp: Path) -> list[tuple[str, list[str], str]]:
    """(case, arguments, a text the error line must hold) for every kind of bad input."""
    data = json.loads(TABLE_III.read_text())
    damaged = {
        "no_pairings": lambda d: d.pop("pairings"),
        "pairings_empty": lambda d: d.__setitem__("pairings", []),
        "env_config_wrong": lambda d: d["env_config"].__setitem__("max_steps", "1000"),
        "trials_too_short": lambda d: d["pairings"][3]["trials"]["evaders_incapacitated"].pop(),
        "count_above_evaders": lambda d: d["pairings"][3]["trials"][
            "evaders_incapacitated"
        ].__setitem__(0, 6),
        "count_a_string": lambda d: d["pairings"][3]["trials"]["evaders_incapacitated"].__setitem__(
            0, "5"
        ),
        "rate_disagrees": lambda d: d["pairings"][3]["trials"]["success_rate"].__setitem__(0, 0.1),
        "no_outcomes": lambda d: d["pairings"][3].pop("trials"),
        "no_source": lambda d: d["pairings"][3]["evader"].pop("source"),
        "meta_trials_huge": lambda d: d["meta"].__setitem__("trials", 10**9),
        "varying_evaders": lambda d: d["env_config"]["evader"].__setitem__("min_agents", 2),
        "policy_without_matches": lambda d: d["meta"]["pursuers"].append("mean-20-5-8"),
    }
    cases = [
        ("missing_file", [str(tmp / "missing.json")], "missing.json: cannot read"),
        ("not_json", [str(_text(tmp / "not_json.json", "{"))], "not_json.json: not JSON"),
        ("a_list", [str(_text(tmp / "a_list.json", "[1, 2]"))], "a_list.json: is not"),
        ("empty_list", [], "no results given"),
        ("a_directory", [str(tmp)], "is a directory"),
        ("mixed_scenes", [str(TABLE_III), str(SCENE_240)], "rate each scene apart"),
        ("bad_anchor", [str(TABLE_III), "--anchor", "nobody"], "--anchor: no evader policy"),
        ("bad_level", [str(TABLE_III), "--level", "1"], "--level must be in (0, 1)"),
        ("bad_resamples", [str(TABLE_III), "--resamples", "0"], "--resamples must be in"),
    ]
    for name, damage in damaged.items():
        broken = copy.deepcopy(data)
        damage(broken)
        path = _write(tmp / f"{name}.json", broken)
        cases.append((name, [str(path)], f"{name}.json"))
    other = copy.deepcopy(data)
    other["env_config"]["max_steps"] = 500
    cases.append(
        ("same_name_other_scene", [str(TABLE_III), str(_write(tmp / "o.json", other))], "max_steps")
    )
    other = copy.deepcopy(data)
    other["meta"]["backend"] = "mjx"
    cases.append(("other_backend", [str(TABLE_III), str(_write(tmp / "b.json", other))], "(mjx)"))
    a, b = _small(data), _small(data)
    for d, mark in ((a, "aaaa"), (b, "bbbb")):
        for p in d["pairings"]:
            p["pursuer"]["fingerprint"] = mark * 8
    b["meta"]["seed"] = 1
    files = [str(_write(tmp / "fa.json", a)), str(_write(tmp / "fb.json", b))]
    cases.append(("two_fingerprints", files, "fingerprint bbbbbbbb here but aaaaaaaa"))
    return cases


def _text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_every_bad_input_is_one_line_naming_it_and_writes_nothing(tmp_path, capsys):
    from pe_mjx.cli import main

    inputs = tmp_path / "inputs"
    inputs.mkdir()
    cases = _bad_inputs(inputs)
    out = tmp_path / "out"
    for name, args, needle in cases:
        with pytest.raises(SystemExit) as exit_:
            main(["rate", "--resamples", "20", *args, "--out", str(out)])  # a case's flag wins
        err = capsys.readouterr().err
        assert exit_.value.code == 2, name
        assert err.startswith("pe-mjx: error: ") and err.count("\n") == 1, (name, err)
        assert needle in err, (name, err)
        assert "Traceback" not in err and not out.exists(), name
    file = _text(tmp_path / "a_file", "x")
    with pytest.raises(SystemExit):
        main(["rate", str(TABLE_III), "--out", str(file)])
    assert "--out:" in capsys.readouterr().err and file.read_text() == "x"


def test_pe_mjx_rate_runs_as_a_console_script(tmp_path):
    """The installed `pe-mjx` on a small results file of the real schema (4 pairings)."""
    small = _write(tmp_path / "results.json", _small(json.loads(TABLE_III.read_text())))
    script = Path(sys.executable).parent / "pe-mjx"
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "pe_mjx.cli"]
    args = ["rate", str(small), "--out", "board", "--resamples", "100"]
    done = subprocess.run(
        [*cmd, *args], cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False
    )
    assert done.returncode == 0, done.stderr
    board = json.loads((tmp_path / "board" / "leaderboard.json").read_text())
    assert [len(board["pursuers"]), len(board["evaders"])] == [2, 2]
    assert board["sources"][0]["pairings"] == 4


@pytest.mark.parametrize("scene", ["20-5-8", "20-5-8-mjx", "240-60-120"])
def test_the_committed_leaderboards_are_those_of_the_committed_results(scene):
    """docs/data/leaderboards/<scene> was written by `pe-mjx rate` from the files it names:
    rated again (point estimates do not depend on the bootstrap), every row is the same, and
    docs/results.md quotes its table unchanged."""
    board = json.loads((LEADERBOARDS / scene / "leaderboard.json").read_text())
    matches = ratings.read_results([ROOT / s["path"] for s in board["sources"]])
    pursuers, evaders = ratings.rate(matches.pairings, resamples=10)
    for team, rows in (("pursuers", pursuers), ("evaders", evaders)):
        assert [r["name"] for r in board[team]] == [r.name for r in rows]
        assert [r["matches"] for r in board[team]] == [r.matches for r in rows]
        assert [r["rating"] for r in board[team]] == pytest.approx([r.rating for r in rows])
    page = (LEADERBOARDS / scene / "leaderboard.md").read_text()
    table = "\n".join(line for line in page.splitlines() if line.startswith("|"))
    assert page.startswith(f"# Leaderboard of {board['scene']}") and table.count("\n") > 5
    assert table in (ROOT / "docs/results.md").read_text()  # the page quotes it as written
