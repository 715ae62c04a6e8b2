"""experiments/results/budget.py: Table III at 10M beside 3M and the paper, and its figure."""

from __future__ import annotations

import json

import pytest

from pe_mjx.paper import PAPER
from pe_mjx.ppo.curves import CURVES_FILE, write_rows
from tests.tool_modules import load_experiment

budget = load_experiment("results", "budget")


def _results(path, cells):
    pairings = [
        {
            "pursuer": {"label": "P_scripted" if p == "scripted" else f"P_{p.upper()}(20,5,8)"},
            "evader": {"label": "E_scripted" if e == "scripted" else f"E_{e.upper()}(20,5,8)"},
            "summary": {"success_rate": s, "success_rate_ci95": 0.01, "per_evader_cost": c},
        }
        for (e, p), (s, c) in cells.items()
    ]
    path.write_text(json.dumps({"meta": {}, "pairings": pairings}))
    return path


def test_each_cell_is_10m_then_3m_then_the_papers(tmp_path):
    ten = _results(
        tmp_path / "ten.json",
        {
            ("mix", "mlp"): (0.5, 3.25),
            ("mlp", "mix"): (1.0, 0.75),
            ("mix", "scripted"): (0.25, 1.5),
        },
    )
    three = _results(tmp_path / "three.json", {("mix", "mlp"): (0.75, 2.5)})
    text = budget.render(budget.cells(ten), budget.cells(three))
    paper = PAPER["III"]["mix", "mlp"]
    rows = [line for line in text.splitlines() if line.startswith("| E_MIX ")]
    success, cost = rows
    assert success == (
        f"| E_MIX | not played | 0.500 ± 0.010 (0.750; {paper[0]:.3f}) | 0.250 ± 0.010 (-; -) |"
    )
    assert cost == f"| E_MIX | not played | 3.250 (2.500; {paper[3]:.3f}) | 1.500 (-; -) |"
    # only the methods with a 10M pairing get a row and a column: no MEAN, no BIRNN
    assert text.count("| Evader \\ Pursuer | P_MIX | P_MLP | P_scripted |") == 2


def test_the_committed_report_is_what_the_committed_data_gives():
    args = budget.Args()
    assert args.out.read_text() == budget.render(budget.cells(args.ten), budget.cells(args.three))


def test_a_missing_or_foreign_evaluation_is_one_line(tmp_path):
    with pytest.raises(SystemExit, match=r"none\.json does not exist"):
        budget.cells(tmp_path / "none.json")
    (tmp_path / "other.json").write_text('{"pairings": [{"pursuer": 1}]}')
    with pytest.raises(SystemExit, match=r"other\.json is not a pe-mjx results\.json"):
        budget.cells(tmp_path / "other.json")


def test_the_figure_draws_the_runs_it_finds(tmp_path):
    for name in ("mix-20-5-8-10m", "mlp-20-5-8-s0"):
        (tmp_path / name).mkdir()
        rows = [
            {"env_steps": s, "wall_time": 0.0, "eval/pursuer_vs_scripted/success_rate": s / 4e3}
            for s in (0, 2048, 4096)
        ]
        write_rows(tmp_path / name / CURVES_FILE, rows)
    path = budget.draw(tmp_path, tmp_path / "fig.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
