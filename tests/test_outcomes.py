"""outcome_counts on hand-built episodes: the same numbers from numpy and jax, batched or not."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from pe_mjx.names import CAPTURE, OBSTACLE, TEAMMATE, WALL
from pe_mjx.outcomes import outcome_counts


def test_counts_of_a_hand_built_episode():
    # 3 pursuers (one hit a wall), 2 evaders (one captured, one crashed into an obstacle).
    cause = np.array([0, WALL, 0, CAPTURE, OBSTACLE])
    distance = np.array([1.0, 2.0, 3.0, 9.0, 9.0])
    out = outcome_counts(cause, distance, num_pursuers=3)
    assert out["pursuers_wall"] == 1 and out["pursuers_active"] == 2
    assert out["evaders_capture"] == 1 and out["evaders_obstacle"] == 1
    assert out["evaders_active"] == 0 and out["evaders_incapacitated"] == 2
    assert out["success_rate"] == 1.0  # SPEC 4: crashed evaders count too
    assert out["pursuit_cost"] == 1
    assert out["travel_distance"] == 2.0  # pursuers only
    assert out["pursuers_teammate"] == 0 and out["evaders_wall"] == 0


def test_batched_numpy_and_jax_agree():
    cause = np.array([[0, TEAMMATE, CAPTURE, 0], [WALL, 0, 0, 0]])
    distance = np.array([[1.0, 3.0, 0.0, 0.0], [0.5, 0.5, 1.0, 1.0]])
    host = outcome_counts(cause, distance, num_pursuers=2)
    device = outcome_counts(jnp.asarray(cause), jnp.asarray(distance), num_pursuers=2)
    assert set(host) == set(device)
    for key in host:
        np.testing.assert_allclose(np.asarray(device[key]), host[key], err_msg=key)
    np.testing.assert_array_equal(host["success_rate"], [0.5, 0.0])
    np.testing.assert_array_equal(host["pursuit_cost"], [1, 1])


def test_travel_distance_of_float32_episodes_is_their_plain_mean():
    # Every pursuer present: exactly the float32 mean (what evaluations reported before absent
    # agents existed), in float32, not a float64 quotient that differs in the last digits.
    rng = np.random.default_rng(0)
    distance = rng.uniform(0.0, 20.0, size=(64, 25)).astype(np.float32)
    cause = np.zeros((64, 25), np.int32)
    out = outcome_counts(cause, distance, num_pursuers=20)
    assert out["travel_distance"].dtype == np.float32
    np.testing.assert_array_equal(out["travel_distance"], distance[:, :20].mean(axis=-1))
