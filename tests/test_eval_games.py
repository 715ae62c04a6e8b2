"""pe_mjx/eval_games.py: the compiled episode programs outlive one evaluation, per scene."""

from __future__ import annotations

import numpy as np

from pe_mjx import eval_games
from pe_mjx.config import get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.evaluate import evaluate
from pe_mjx.policy.resolve import resolve_policy

ARGS = dict(trials=2, seed=0, backend="kinematic", record=1)


def _compiles(lines: list[str]) -> list[str]:
    return [line for line in lines if "compiling" in line]


def test_a_second_evaluation_of_the_scene_reuses_the_compiled_programs(tmp_path):
    eval_games.clear_programs()
    said: list[list[str]] = [[], []]
    first, again = (
        evaluate(
            ["mix-20-5-8"], ["scripted"], "2-1-1", tmp_path / f"run{i}", log=said[i].append, **ARGS
        )
        for i in (0, 1)
    )
    # The first compiles the trials' program and the recording's; the second neither.
    assert len(_compiles(said[0])) == 2, said[0]
    assert _compiles(said[1]) == [], said[1]
    (a,), (b,) = first["results"], again["results"]
    assert b.seconds < a.seconds / 3, (a.seconds, b.seconds)
    assert a.summary == b.summary
    for key in a.trials:
        np.testing.assert_array_equal(a.trials[key], b.trials[key])
    assert (tmp_path / "run0" / "trials.csv").read_text() == (
        tmp_path / "run1" / "trials.csv"
    ).read_text()


def _programs(preset: str, pairs: list[tuple[str, str]]) -> list[object]:
    """The program `Games` hands each (pursuer, evader) pair of `preset` (nothing compiles)."""
    config = get_preset(preset)
    games = eval_games.Games(PursuitEvasionEnv(config, "kinematic"))
    return [
        games._program(
            resolve_policy(p, "pursuer", config), resolve_policy(e, "evader", config), False
        )
        for p, e in pairs
    ]


def test_programs_are_per_scene_and_policy_shapes_and_bounded(monkeypatch):
    eval_games.clear_programs()
    a, b, c = _programs("2-1-1", [("scripted", "scripted")] * 2 + [("random", "scripted")])
    assert a is b and c is not a
    (other_scene,) = _programs("4-1-2", [("scripted", "scripted")])
    assert other_scene is not a
    # At most PROGRAMS_KEPT, the least recently used dropped first.
    eval_games.clear_programs()
    monkeypatch.setattr(eval_games, "PROGRAMS_KEPT", 2)
    ss, rs = ("scripted", "scripted"), ("random", "scripted")
    first = _programs("2-1-1", [ss, rs, ss])
    assert first[2] is first[0]  # kept, and now the most recently used
    later = _programs("2-1-1", [("scripted", "random"), ss, rs])  # the third drops rs
    assert later[1] is first[0] and later[2] is not first[1]
