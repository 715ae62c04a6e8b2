"""experiments/results/paper_findings.py on a small made-up table: the per-method means and the
evader duels."""

from __future__ import annotations

import json

from tests.tool_modules import load_experiment


def _load():
    return load_experiment("results", "paper_findings")


# success[evader][pursuer]: every method's pursuers and evaders, and the scripted teams
SUCCESS = {
    "mix": {"mix": 0.90, "mean": 0.80, "birnn": 0.70, "mlp": 0.60, "scripted": 0.50},
    "mean": {"mix": 0.95, "mean": 0.85, "birnn": 0.75, "mlp": 0.65, "scripted": 0.55},
    "birnn": {"mix": 1.00, "mean": 0.99, "birnn": 0.98, "mlp": 0.97, "scripted": 0.96},
}


def _table() -> dict:
    pairings = []
    for e, row in SUCCESS.items():
        for p, success in row.items():
            summary = {"success_rate": success, "per_evader_cost": 1.0, "travel_distance": 5.0}
            pairings.append(
                {
                    "pursuer": {"source": p if p == "scripted" else f"runs/{p}-20-5-8-3m"},
                    "evader": {"source": f"runs/{e}-20-5-8-3m"},
                    "summary": summary,
                }
            )
    return {"pairings": pairings}


def test_a_duel_is_over_the_pursuers_both_evaders_met_and_neither_trained():
    duels = _load().duels(_table())
    assert set(duels) == {"mix-mean", "mix-birnn", "mean-birnn"}
    # MIX and MEAN evaders both met P_BIRNN and P_MLP; their own and the scripted ones do not count
    assert duels["mix-mean"]["against"] == ["birnn", "mlp"]
    assert abs(duels["mix-mean"]["mix"] - 0.65) < 1e-9
    assert abs(duels["mix-mean"]["mean"] - 0.70) < 1e-9
    assert duels["mean-birnn"]["against"] == ["mix", "mlp"]
    assert abs(duels["mean-birnn"]["birnn"] - 0.985) < 1e-9


def test_the_findings_files_carry_the_duels(tmp_path):
    module = _load()
    (tmp_path / "table-III").mkdir()
    (tmp_path / "table-III" / "results.json").write_text(json.dumps(_table()))
    module.main(module.Args(data=tmp_path))
    findings = json.loads((tmp_path / "findings.json").read_text())["table-III"]
    assert findings["duels"]["mix-mean"]["against"] == ["birnn", "mlp"]
    # the per-method mean of MIX's evaders is over the other three learned pursuers
    assert abs(findings["evaders"]["mix"]["success_conceded"] - 0.70) < 1e-9
    assert "| mix vs mean | 0.650 | 0.700 | birnn, mlp |" in (tmp_path / "findings.md").read_text()
