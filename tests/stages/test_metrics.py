"""pe_mjx.stages.metrics: reward sums over the valid agents, episode counts as outcome_counts."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.names import CAPTURE, REWARD_TERMS, WALL
from pe_mjx.stages.metrics import step_metrics
from pe_mjx.stages.rewards import zero_terms
from pe_mjx.stages.world import World
from tests.conftest import SMALL

CFG = get_preset(SMALL)


def test_step_metrics_by_hand():
    world = World(
        pos=jnp.zeros((3, 2)),
        yaw=jnp.zeros(3),
        vel=jnp.zeros((3, 2)),
        active=jnp.asarray([False, True, False]),
        cause=jnp.asarray([WALL, 0, CAPTURE], jnp.int32),
        distance=jnp.asarray([1.0, 3.0, 2.0]),
        captures=jnp.asarray([0, 1, 1], jnp.int32),
        obstacles=jnp.zeros((1, 3)),
        step=jnp.asarray(7, jnp.int32),
    )
    terms = zero_terms(CFG)
    terms["pursuer"]["capture"] = jnp.asarray([5.0, 7.0])
    valid = {"pursuer": jnp.asarray([False, True]), "evader": jnp.asarray([True])}
    m = step_metrics(CFG, world, terms, valid, jnp.asarray(2.0))
    names = {f"reward/{t}/{n}" for t, ns in REWARD_TERMS.items() for n in ns}
    assert names <= set(m)
    assert float(m["reward/pursuer/capture"]) == 7.0  # pursuer 0 was not valid
    want = {
        "invalid_actions": 2.0,
        "episode/pursuer_wall": 1.0,
        "episode/pursuer_capture": 0.0,
        "episode/evader_capture": 1.0,
        "episode/pursuer_distance": 2.0,
        "episode/evader_distance": 2.0,
        "episode/captures": 1.0,
        "episode/success_rate": 1.0,
        "episode/pursuit_cost": 1.0,
        "episode/length": 7.0,
    }
    for key, value in want.items():
        assert float(m[key]) == pytest.approx(value), key
    for key, value in m.items():
        assert value.shape == () and value.dtype == np.float32, key
