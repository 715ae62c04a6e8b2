"""pe_mjx.stages.observations: block shapes, a hand-checked own block, the env's `observe`."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.config import get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.names import FEATURES, MASK_KEYS, TEAMS
from pe_mjx.stages.geometry import geometry
from pe_mjx.stages.masks import mask_table
from pe_mjx.stages.observations import entity_observations, observe, team_slices
from pe_mjx.stages.world import World
from tests.conftest import SMALL

CFG = get_preset(SMALL)


def world() -> World:
    n = CFG.num_agents
    return World(
        pos=jnp.asarray([[1.0, 0.0], [-0.5, 0.5], [0.0, -1.0]]),
        yaw=jnp.asarray([math.pi / 2, 0.0, 1.0]),
        vel=jnp.asarray([[0.0, 0.1], [0.0, 0.0], [0.2, 0.0]]),
        active=jnp.asarray([True, False, True]),
        cause=jnp.zeros(n, jnp.int32),
        distance=jnp.zeros(n),
        captures=jnp.zeros(n, jnp.int32),
        obstacles=jnp.asarray([[0.0, 1.2, 0.3]]),
        step=jnp.zeros((), jnp.int32),
    )


def test_team_slices_pursuers_first():
    assert team_slices(CFG) == {"pursuer": slice(0, 2), "evader": slice(2, 3)}


def test_blocks_and_the_own_features_by_hand():
    w = world()
    obs = entity_observations(CFG, w, geometry(w.pos, w.yaw, w.obstacles))
    sizes = {"pursuer": 2, "evader": 1}
    k = CFG.arena.num_obstacles
    for team in TEAMS:
        a, o = sizes[team], 3 - sizes[team]
        entities = {"own": (), "teammates": (a - 1,), "opponents": (o,), "obstacles": (k,)}
        for key, rest in entities.items():
            assert obs[team][key].shape == (a, *rest, FEATURES[key]), (team, key)
        for key, mask in MASK_KEYS.items():
            assert (
                obs[team][mask].shape == (a, *entities[key]) and np.asarray(obs[team][mask]).all()
            )
        assert "action_mask" not in obs[team]
    # pursuer 0 at (1, 0) facing +y, moving at 0.1 m/s: the centre is 1 m to its left
    np.testing.assert_allclose(
        np.asarray(obs["pursuer"]["own"][0]), [0.0, 1 / 2.0, 0.0, 1.0, 0.1 / 0.2], atol=1e-6
    )
    assert float(obs["pursuer"]["own"][1, 0]) == 1.0  # downed flag
    assert float(obs["evader"]["opponents"][0, 1, 0]) == 1.0  # the evader sees it downed


def test_observe_is_the_envs():
    env = PursuitEvasionEnv(CFG, backend="kinematic")
    w = world()
    tables = {t: mask_table(CFG, t) for t in TEAMS}
    ours = observe(CFG, tables, w, geometry(w.pos, w.yaw, w.obstacles))
    theirs = jax.jit(env.observe)(w)
    assert jax.tree.structure(ours) == jax.tree.structure(theirs)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-6)
