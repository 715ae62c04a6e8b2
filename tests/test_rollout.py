"""rollout: acting for both teams (one key split for every caller) and freezing finished arenas."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.names import TEAMS
from pe_mjx.rollout import act, freeze


class Fake(NamedTuple):
    done: jax.Array
    x: jax.Array


def test_freeze_keeps_finished_arenas_batched_and_not():
    old = Fake(done=jnp.array([1.0, 0.0]), x=jnp.zeros((2, 3)))
    new = Fake(done=jnp.array([1.0, 1.0]), x=jnp.ones((2, 3)))
    out = freeze(old, new)
    np.testing.assert_array_equal(out.x, [[0, 0, 0], [1, 1, 1]])
    np.testing.assert_array_equal(out.done, [1.0, 1.0])
    one = freeze(Fake(jnp.float32(0), jnp.zeros(3)), Fake(jnp.float32(1), jnp.ones(3)))
    np.testing.assert_array_equal(one.x, np.ones(3))


def test_act_gives_each_team_its_own_key_in_team_order():
    seen = {}

    def recorder(team):
        def policy(obs, rng):
            seen[team] = jax.random.key_data(rng)
            return jnp.zeros(obs["own"].shape[0], jnp.int32)

        return policy

    obs = {t: {"own": jnp.zeros((2, 5))} for t in TEAMS}
    rng = jax.random.key(0)
    actions, carry = act({t: recorder(t) for t in TEAMS}, obs, rng)
    expected_carry, *team_keys = jax.random.split(rng, len(TEAMS) + 1)
    for team, key in zip(TEAMS, team_keys, strict=True):
        np.testing.assert_array_equal(seen[team], jax.random.key_data(key))
        assert actions[team].shape == (2,)
    np.testing.assert_array_equal(jax.random.key_data(carry), jax.random.key_data(expected_carry))


def test_act_needs_every_team():
    with pytest.raises(KeyError):
        act({"pursuer": lambda o, r: o}, {t: {} for t in TEAMS}, jax.random.key(0))
