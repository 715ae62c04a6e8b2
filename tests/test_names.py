"""pe_mjx.names: jax-free, and the single source the other modules read."""

from __future__ import annotations

import ast
from pathlib import Path

import jax
import pytest

from pe_mjx import env, names, networks, trajectory
from pe_mjx.policy import inference, scripted


def test_names_imports_nothing_but_the_standard_library():
    tree = ast.parse(Path(names.__file__).read_text())
    imported = {
        n.module if isinstance(n, ast.ImportFrom) else a.name
        for n in ast.walk(tree)
        if isinstance(n, ast.Import | ast.ImportFrom)
        for a in n.names
    }
    assert imported == {"__future__"}


def test_other_modules_read_the_same_objects():
    assert env.BACKENDS is names.BACKENDS
    assert networks.MASK_KEYS is names.MASK_KEYS and inference.MASK_KEYS is names.MASK_KEYS
    assert tuple(scripted.POLICIES) == names.BUILTIN_POLICIES
    assert trajectory.NUM_CAUSES == names.NUM_CAUSES == len(names.CAUSE_NAMES) + 1


@pytest.mark.parametrize("team", names.TEAMS)
def test_sizes_match_the_env_observation(team):
    config = env.get_preset("4-1-2")
    game = env.PursuitEvasionEnv(config, backend="kinematic")
    obs = jax.eval_shape(game.reset, jax.random.key(0)).obs[team]  # traced, not compiled
    for key, size in names.FEATURES.items():
        assert obs[key].shape[-1] == size
    assert set(names.MASK_KEYS.values()) < set(obs)
    dummy = inference.dummy_obs(config, team)
    assert {k: v.shape for k, v in dummy.items()} == {k: v.shape for k, v in obs.items()}


def test_other_team():
    assert names.other_team("pursuer") == "evader" and names.other_team("evader") == "pursuer"
    with pytest.raises(ValueError, match="unknown team"):
        names.other_team("referee")
