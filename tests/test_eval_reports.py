"""pe_mjx/eval_reports.py: how an evaluation's results are written."""

from __future__ import annotations

import json

from pe_mjx.eval_reports import code_provenance, dumps, provenance_text


def test_results_json_writes_per_trial_lists_on_one_line_and_whole_numbers_bare():
    payload = {
        "meta": {"trials": 3, "radius": 5.0, "names": ["a", "b"]},
        "trials": {
            "success_rate": [1.0, 0.8, 0.0, -2.0],
            "travel_distance": [19.138221225738526, 1e20, 2.5e-07, 10.05],
            "captures": [3, 0],
            "empty": [],
        },
    }
    text = dumps(payload)
    assert '"success_rate": [1, 0.8, 0, -2]' in text
    assert '"travel_distance": [19.138221225738526, 1e+20, 2.5e-07, 10.05]' in text
    assert '"captures": [3, 0]' in text
    assert '"radius": 5.0' in text  # a scalar keeps its type; only the lists are compacted
    assert json.loads(text) == payload  # the same numbers (JSON's 1 == 1.0)


def test_provenance_counts_each_reports_code_version():
    clean = {"code_version": {"git_commit": "a" * 40, "git_dirty": False}}
    dirty = {"code_version": {"git_commit": "b" * 40, "git_dirty": True}}
    counts = code_provenance([clean, dirty, dirty, {}])
    assert counts == {"clean": 1, "dirty": 2, "not_recorded": 1}
    assert provenance_text(counts) == "1 of 4 clean commit, 2 of 4 dirty tree, 1 of 4 not recorded"
    assert provenance_text(code_provenance([clean, clean])) == "clean commit"
