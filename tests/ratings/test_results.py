"""Reading results.json files (`pe_mjx.ratings.results`): policy names, and files of one scene
combined with a pairing played on the same arenas counted once. Every kind of bad file is in
test_board.py, through `pe-mjx rate` and its one-line errors."""

from __future__ import annotations

import copy
import json
from pathlib import Path

from pe_mjx.ratings import results

ROOT = Path(__file__).resolve().parents[2]
TABLE_III = ROOT / "docs/data/paper-3m/table-III/results.json"


def test_shipped_policies_are_named_however_they_were_given():
    assert results.policy_name("assets/policies/mix-20-5-8-3m") == "mix-20-5-8-3m"
    assert results.policy_name("/x/pe_mjx/assets/policies/mix-20-5-8/") == "mix-20-5-8"
    assert results.policy_name("mix-20-5-8-3m") == "mix-20-5-8-3m"
    assert results.policy_name("train/runs/mix-20-5-8-s0") == "train/runs/mix-20-5-8-s0"


def test_files_of_one_scene_combine_and_a_pairing_on_the_same_arenas_counts_once(tmp_path):
    """Files of one scene that played the same pairing with the same seed and trial count (the
    same arenas) count it once, and say whether its games were the same ones (captures trial
    for trial). Built from Table III's file, so that no later re-run of the data changes it."""
    data = json.loads(TABLE_III.read_text())
    scripted = [
        p for p in data["pairings"] if p["pursuer"]["source"] == p["evader"]["source"] == "scripted"
    ]
    assert len(scripted) == 1
    other = copy.deepcopy(scripted)
    trials = other[0]["trials"]  # one trial's captures differ: other games
    trials["evaders_incapacitated"][0] = 5 - trials["evaders_incapacitated"][0]
    trials["success_rate"][0] = trials["evaders_incapacitated"][0] / 5
    files = {"same.json": scripted, "other.json": other}
    for name, pairings in files.items():
        meta = {**data["meta"], "pursuers": ["scripted"], "evaders": ["scripted"]}
        (tmp_path / name).write_text(json.dumps({**data, "meta": meta, "pairings": pairings}))
    matches = results.read_results([TABLE_III, *(tmp_path / name for name in files)])
    assert (matches.scene, matches.backend, len(matches.pairings)) == ("20-5-8", "kinematic", 25)
    for source, same in zip(matches.sources[1:], (True, False), strict=True):
        assert source["counted_before"] == [
            {
                "pursuer": "scripted",
                "evader": "scripted",
                "counted_from": str(TABLE_III),
                "same_games": same,
            }
        ]
    assert matches.labels["pursuer", "mix-20-5-8-3m"] == "P_MIX(20,5,8)"
    data = json.loads(TABLE_III.read_text())
    first = data["pairings"][0]
    assert matches.pairings[0].captured.tolist() == first["trials"]["evaders_incapacitated"]
    assert matches.pairings[0].matches == 100 * 5
