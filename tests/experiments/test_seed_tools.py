"""experiments/results/seed_spread.py and the seed figures of experiments/results/coev_curves.py,
on small made-up inputs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.tool_modules import EXPERIMENTS, load_experiment


def _load(name: str):
    return load_experiment("results", name)


META = {"preset": "20-5-8", "trials": 100, "seed": 0, "backend": "kinematic"}


def _evaluation(path: Path, success: float, length: float, extra=(), **meta) -> Path:
    summary = {
        "success_rate": success,
        "travel_distance": 10.0 * success,
        "pursuit_cost": 5.0,
        "per_evader_cost": 5.0 / (5 * success),
        "length": length,
    }
    pairings = [
        {"pursuer": {"label": p}, "evader": {"label": e}, "summary": summary}
        for p, e in [("P_MIX(20,5,8)", "E_MIX(20,5,8)"), ("P_scripted", "E_MIX(20,5,8)"), *extra]
    ]
    path.mkdir()
    (path / "results.json").write_text(json.dumps({"meta": META | meta, "pairings": pairings}))
    return path


def test_seed_spread_gives_mean_std_and_range_over_seeds(tmp_path):
    runs = [
        _evaluation(tmp_path / f"s{i}", s, n)
        for i, (s, n) in enumerate([(0.9, 500), (0.8, 700), (1.0, 600)])
    ]
    # seed 0's evaluation is a larger table: its other pairings are left out and listed
    runs[0] = _evaluation(tmp_path / "table", 0.9, 500, extra=[("P_MEAN(20,5,8)", "E_MIX(20,5,8)")])
    out = tmp_path / "seeds"
    subprocess.run(
        [
            sys.executable,
            str(EXPERIMENTS / "results" / "seed_spread.py"),
            *map(str, runs),
            "--out",
            str(out),
        ],
        check=True,
        capture_output=True,
    )
    data = json.loads((out / "seeds.json").read_text())
    first = data["pairings"][0]
    assert (first["pursuer"], first["evader"]) == ("P_MIX(20,5,8)", "E_MIX(20,5,8)")
    assert first["success_rate"]["values"] == [0.9, 0.8, 1.0]
    assert first["success_rate"]["mean"] == pytest.approx(0.9)
    assert first["success_rate"]["std"] == pytest.approx(0.1)
    assert (first["length"]["min"], first["length"]["max"]) == (500, 700)
    assert (
        "| E_MIX(20,5,8) | P_MIX(20,5,8) | 0.900 ± 0.100 [0.800, 1.000] |"
        in (out / "seeds.md").read_text()
    )


def test_seed_spread_refuses_evaluations_it_cannot_compare_in_one_line(tmp_path):
    a = _evaluation(tmp_path / "a", 0.9, 500)
    b = tmp_path / "b"
    b.mkdir()
    (b / "results.json").write_text(json.dumps({"meta": META, "pairings": []}))
    c = tmp_path / "c"
    c.mkdir()
    (c / "results.json").write_text("{not json")
    tool = str(EXPERIMENTS / "results" / "seed_spread.py")
    for other, says in [
        (b, "no pairing"),
        (_evaluation(tmp_path / "e", 0.9, 500, preset="16-4-4"), "not the same evaluation"),
        (c, "not a pe-mjx results.json"),
        (tmp_path / "d", "does not exist"),
    ]:
        proc = subprocess.run(
            [sys.executable, tool, str(a), str(other), "--out", str(tmp_path / "o")],
            capture_output=True,
            text=True,
        )
        assert proc.returncode != 0
        assert says in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert not (tmp_path / "o").exists()


def test_curves_of_seeds_are_grouped_by_run_name_and_drawn(tmp_path):
    curves = _load("coev_curves")
    tag = "eval/evader_vs_scripted/length"
    data = {
        "mix-20-5-8-s0": {tag: [[100, 50.0], [200, 60.0], [300, 70.0]]},
        "mix-20-5-8-s1": {tag: [[200, 80.0], [300, 90.0]]},
        "mean-20-5-8-s0": {tag: [[100, 1.0]]},
    }
    assert curves.seed_groups(data) == {"mix-20-5-8": ["mix-20-5-8-s0", "mix-20-5-8-s1"]}
    (path,) = curves.draw_seeds(data, tmp_path)
    assert path.name == "curves-mix-20-5-8-seeds.png" and path.stat().st_size > 10_000


def test_seed_spread_matrix_lays_pairings_out_as_evaders_by_pursuers(tmp_path):
    spread = _load("seed_spread")
    extra = [("P_MEAN(20,5,8)", "E_MIX(20,5,8)"), ("P_MIX(20,5,8)", "E_scripted")]
    runs = [_evaluation(tmp_path / f"s{i}", s, 600, extra=extra) for i, s in enumerate([0.5, 0.7])]
    out = tmp_path / "seeds"
    spread.main(spread.Args(evaluations=tuple(runs), out=out, matrix=("success_rate",)))
    text = (out / "seeds.md").read_text()
    header = "| Evader \\ Pursuer | P_MIX(20,5,8) | P_scripted | P_MEAN(20,5,8) |"
    assert header in text
    # E_scripted met only P_MIX: the other cells of its row are "-"
    assert "| E_scripted | 0.600 ± 0.141 [0.500, 0.700] | - | - |" in text
    assert text.count("| E_MIX(20,5,8) | 0.600 ± 0.141 [0.500, 0.700] |") == 1
    with pytest.raises(SystemExit, match="--matrix: unknown metric 'wins'"):
        spread.main(spread.Args(evaluations=tuple(runs), out=out, matrix=("wins",)))
