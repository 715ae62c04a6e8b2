"""experiments/results/ablations.py: each ablation's telling pairings and sentence, read from an
evaluation's results.json by policy source; nothing before the evaluation exists."""

from __future__ import annotations

import itertools
import json

from tests.tool_modules import load_experiment

TEAMS = ("runs/abl", "ours", "scripted")


def _results(path, teams=TEAMS):
    """An evaluation of every pursuer against every evader of `teams` whose success rate encodes
    its pairing: pursuer index / 10 + evader index / 100 (so every pairing the script reads has
    its own value)."""
    pairings = []
    for (i, p), (j, e) in itertools.product(enumerate(teams), enumerate(teams)):
        summary = {"success_rate": 0.5 + i / 10 + j / 100, "per_evader_cost": 1 + i + j / 10}
        pairings.append({"pursuer": {"source": p}, "evader": {"source": e}, "summary": summary})
    path.mkdir(parents=True)
    (path / "results.json").write_text(json.dumps({"meta": {"trials": 7}, "pairings": pairings}))


def test_an_ablation_is_read_by_policy_source_and_worded(tmp_path, monkeypatch):
    module = load_experiment("results", "ablations")
    monkeypatch.setattr(module, "DATA", tmp_path)
    spec = {"what": "x", "evaluation": "abl/e", "ablated": "abl", "ours": "ours"}
    assert module.effect(spec) is None  # not evaluated yet
    _results(tmp_path / "abl" / "e")
    got = module.effect(spec)
    rows = {
        k: (v["ablated"]["success_rate"], v["ours"]["success_rate"])
        for k, v in got["pairings"].items()
    }
    assert rows == {
        "scripted_pursuers": (0.7, 0.71),  # scripted (2) vs abl (0), vs ours (1)
        "scripted_evader": (0.52, 0.62),
        "cross": (0.51, 0.6),
        "self": (0.5, 0.61),
    }
    assert got["pairings"]["scripted_evader"]["ablated"]["per_evader_cost"] == 1.2
    assert got["trials"] == 7
    assert got["text"] == (
        "x (`abl` against `ours`, `docs/data/abl/e`, 7 trials): the scripted pursuers catch "
        "0.700 of its evaders (ours 0.710); its pursuers catch 0.520 of the scripted evader at "
        "1.200 per evader (ours 0.620 at 2.200); across, its pursuers catch 0.510 of our "
        "evaders and ours 0.600 of its"
    )
    table = module.markdown({"k": got})
    assert (
        "| k | its pursuers against the scripted evader | 0.520 [1.200] | 0.620 [2.200] |" in table
    )


def test_an_ablation_with_a_third_co_evolution_is_set_against_it_too(tmp_path, monkeypatch):
    """`also` adds both cross pairings with a third co-evolution, for the ablated one and ours."""
    module = load_experiment("results", "ablations")
    monkeypatch.setattr(module, "DATA", tmp_path)
    spec = {"what": "x", "evaluation": "abl/e", "ablated": "abl", "ours": "ours", "also": "big"}
    _results(tmp_path / "abl" / "e", teams=(*TEAMS, "big"))
    got = module.effect(spec)
    pairs = {
        k: (v["ablated"]["success_rate"], v["ours"]["success_rate"])
        for k, v in got["pairings"].items()
    }
    assert pairs["against_also"] == (0.53, 0.63)  # abl (0) and ours (1) against big (3)
    assert pairs["also_against"] == (0.8, 0.81)  # big (3) against abl (0) and ours (1)
    assert pairs["cross"] == (0.51, 0.6)  # unchanged by the third
    assert got["text"].endswith(
        "; against `big`, its pursuers catch 0.530 of those evaders (ours 0.630) and those "
        "pursuers 0.800 of its evaders (of ours 0.810)"
    )
    table = module.markdown({"k": got})
    assert (
        "| k | the pursuers of `big` against its evaders | 0.800 [4.000] | 0.810 [4.100] |" in table
    )
