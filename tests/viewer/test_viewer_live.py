"""The live run behind the viewer: fitting policies, stepping, freezing, counters, attention."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.viewer.live import (
    LiveRun,
    PolicyError,
    attention_targets,
    load_team_policy,
)
from tests.viewer.browser import require_chromium


def test_unknown_policy_names_and_paths_are_clear_errors(tmp_path):
    config = get_preset("2-1-1")
    with pytest.raises(PolicyError, match="not one of scripted, random and no such directory"):
        load_team_policy("/no/such/run", config, "pursuer")
    with pytest.raises(PolicyError, match="no pursuer policy"):
        load_team_policy("", config, "pursuer")
    with pytest.raises(PolicyError, match="unknown team"):
        load_team_policy("scripted", config, "referee")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(PolicyError, match="holds no checkpoints"):
        load_team_policy(str(empty), config, "evader")


def test_checkpoint_team_and_action_size_must_fit(tiny_run):
    config = get_preset("2-1-1")
    with pytest.raises(PolicyError, match="did not learn a evader policy"):
        load_team_policy(str(tiny_run.run_dir), config, "evader")
    other = config.replace(pursuer=dataclasses.replace(config.pursuer, num_turn_rates=7))
    with pytest.raises(PolicyError, match="has 39 actions but this scene's pursuers have 21"):
        load_team_policy(str(tiny_run.run_dir), other, "pursuer")
    policy = load_team_policy(str(tiny_run.run_dir), get_preset("8-2-4"), "pursuer")
    assert policy.attention_apply is not None  # MIX runs on other entity counts


def test_attention_targets_follow_the_observation_order():
    config = get_preset("4-1-2")
    index, kinds = attention_targets(config, "pursuer")
    np.testing.assert_array_equal(index[0], [1, 2, 3, 4])
    np.testing.assert_array_equal(index[2], [0, 1, 3, 4])
    assert kinds == ("teammates",) * 3 + ("opponents",) + ("obstacles",) * 2
    index, kinds = attention_targets(config, "evader")
    np.testing.assert_array_equal(index[0], [0, 1, 2, 3])
    assert kinds == ("opponents",) * 4 + ("obstacles",) * 2


def test_live_run_steps_freezes_finished_arenas_and_shows_attention(tiny_run):
    config = get_preset("2-1-1").replace(max_steps=4)
    policies = {
        "pursuer": load_team_policy(str(tiny_run.run_dir), config, "pursuer"),
        "evader": load_team_policy("random", config, "evader"),
    }
    run = LiveRun(config, policies, num_arenas=2, backend="kinematic", seed=1)
    first = run.frame()
    assert first.poses.shape == (2, 3, 3) and first.obstacles.shape == (2, 1, 3)
    assert run.counters()[0]["time"] == 0.0 and run.counters()[0]["pursuers"] == 2
    for _ in range(4):
        run.step()
    assert run.done
    rows = run.counters()
    assert all(row["done"] for row in rows)
    assert all(row["time"] <= 4 * config.control_dt + 1e-6 for row in rows)
    final = run.frame()
    run.step()  # finished arenas freeze
    np.testing.assert_array_equal(run.frame().poses, final.poses)

    overlay = run.attention("pursuer", arena=1, agent=1)
    assert overlay is not None and overlay.agent == 1 and overlay.arena == 1
    assert overlay.targets.shape == (3, 2) and overlay.kinds[0] == "teammates"
    np.testing.assert_allclose(overlay.targets[0], run.positions()[1, 0])  # pursuer 0
    own = run.own_attention("pursuer", 1, 1)
    np.testing.assert_allclose(own + overlay.weights.sum(), 1.0, atol=1e-5)
    assert run.attention("evader", 0, 0) is None  # random has no attention

    run.reset(1)
    np.testing.assert_array_equal(run.frame().poses, first.poses)  # same seed, same arenas
    run.reset(2)
    assert not np.array_equal(run.frame().poses, first.poses)


def test_require_chromium_fails_under_ci(monkeypatch):
    monkeypatch.setenv("CHROMIUM", "/no/such/chromium")
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI is set but no Chromium"):
        require_chromium()
    monkeypatch.setenv("CI", "false")
    with pytest.raises(pytest.skip.Exception):
        require_chromium()


def test_a_viewer_plays_the_policies_it_is_given_without_loading_them_again(monkeypatch):
    """`pe-mjx view` resolves --pursuers/--evaders once (for its error lines) and hands them to
    the viewer: the first live run plays those, restoring no checkpoint a second time."""
    from pe_mjx.config import get_preset
    from pe_mjx.names import TEAMS
    from pe_mjx.viewer import commands, start_viewer
    from pe_mjx.viewer.live import load_team_policy

    config = get_preset("2-1-1")
    given = {t: load_team_policy("scripted", config, t) for t in TEAMS}
    loaded = []

    def counting(*args, **kwargs):
        loaded.append(args[0])
        return load_team_policy(*args, **kwargs)

    monkeypatch.setattr(commands, "load_team_policy", counting)
    viewer = start_viewer(
        preset="2-1-1", backend="kinematic", pursuers="scripted", evaders="scripted", port=0,
        verbose=False, policies=given,
    )  # fmt: skip
    try:
        assert loaded == []
        assert all(viewer.source.run.policies[t] is given[t] for t in TEAMS)
    finally:
        viewer.stop()
