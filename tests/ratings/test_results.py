"""Reading results.json files (`pe_mjx.ratings.results`): policy names, and files of one scene
combined with a pairing played on the same arenas counted once. Every kind of bad file is in
test_board.py, through `pe-mjx rate` and its one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

from pe_mjx.ratings import results

ROOT = Path(__file__).resolve().parents[2]
TABLE_III = ROOT / "docs/data/paper-3m/table-III/results.json"
TABLE_III_1M = ROOT / "docs/data/paper/table-III/results.json"


def test_shipped_policies_are_named_however_they_were_given():
    assert results.policy_name("assets/policies/mix-20-5-8-3m") == "mix-20-5-8-3m"
    assert results.policy_name("/x/pe_mjx/assets/policies/mix-20-5-8/") == "mix-20-5-8"
    assert results.policy_name("mix-20-5-8-3m") == "mix-20-5-8-3m"
    assert results.policy_name("train/runs/mix-20-5-8-s0") == "train/runs/mix-20-5-8-s0"


def test_files_of_one_scene_combine_and_a_pairing_on_the_same_arenas_counts_once():
    """The 1M and 3M Table III share the scripted teams: their scripted-against-scripted
    pairing (same seed, same trial count: the same arenas) is the same games, counted once."""
    matches = results.read_results([TABLE_III, TABLE_III_1M])
    assert (matches.scene, matches.backend, len(matches.pairings)) == ("20-5-8", "kinematic", 49)
    assert matches.sources[1]["counted_before"] == [
        {
            "pursuer": "scripted",
            "evader": "scripted",
            "counted_from": str(TABLE_III),
            "same_games": True,
        }
    ]
    assert matches.labels["pursuer", "mix-20-5-8-3m"] == "P_MIX(20,5,8)"
    data = json.loads(TABLE_III.read_text())
    first = data["pairings"][0]
    assert matches.pairings[0].captured.tolist() == first["trials"]["evaders_incapacitated"]
    assert matches.pairings[0].matches == 100 * 5
