"""The PPO loss and the per-agent GAE masking, against numbers worked out by hand.

In the style of Brax's `losses_test.py`: tiny inputs, every expected value derived in the comments
from the formulas, so a change in the trainer's densest logic shows up as a wrong number.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.ppo.losses import TeamBatch, ppo_loss, team_targets

GAMMA = LAMBDA = 0.5


def _targets():
    # T = 3 steps, B = 1 arena, A = 3 agents; columns are agents a, b, c.
    #   a: active throughout.
    #   b: captured at t = 1 (its trajectory terminates), down at t = 2 (invalid).
    #   c: truncated at t = 1 (time limit), then a fresh episode after the auto-reset at t = 2.
    col = np.array([1.0, 1.0, 1.0])
    reward = np.stack([col, [2.0, -10.0, 2.0], [3.0, 0.0, 3.0]])
    value = np.stack([0.5 * col, 1.0 * col, 1.5 * col])
    data = {
        "reward": reward,
        "value": value,
        "termination": np.array([[0, 0, 0], [0, 1, 0], [0, 1, 0]], float),
        "truncation": np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]], float),
        "valid": np.array([[1, 1, 1], [1, 1, 1], [1, 0, 1]], float),
    }
    data = {k: jnp.asarray(v[:, None, :], jnp.float32) for k, v in data.items()}
    bootstrap = jnp.full((1, 3), 2.0)
    adv, returns, mask = team_targets(data, bootstrap, GAMMA, LAMBDA)
    return np.asarray(adv[:, 0]), np.asarray(returns[:, 0]), np.asarray(mask[:, 0])


def test_gae_of_an_agent_active_throughout():
    # delta_t = r_t + g v_{t+1} - v_t = 1.0, 1.75, 2.5 (v_3 = bootstrap 2.0);
    # acc_t = delta_t + g l acc_{t+1} = 1.59375, 2.375, 2.5; vs_t = acc_t + v_t = 2.09375, 3.375, 4;
    # Brax's advantage: r_t + g vs_{t+1} - v_t = 1 + 1.6875 - 0.5, 2 + 2 - 1, 3 + 1 - 1.5.
    adv, returns, mask = _targets()
    np.testing.assert_allclose(adv[:, 0], [2.1875, 3.0, 2.5], rtol=1e-6)
    np.testing.assert_allclose(returns[:, 0], [2.6875, 4.0, 4.0], rtol=1e-6)
    np.testing.assert_array_equal(mask[:, 0], [1, 1, 1])


def test_gae_stops_at_a_capture_and_masks_the_downed_agent():
    # Capture at t = 1: no bootstrap past it, delta_1 = -10 - 1 = -11, acc_1 = -11 (the recursion
    # is cut), vs_1 = -10; t = 0: 1 + 0.5 * (-10) - 0.5 = -4.5. t = 2 is a downed agent's step:
    # delta_2 = 0 - 1.5, masked out of every loss.
    adv, _, mask = _targets()
    np.testing.assert_allclose(adv[:, 1], [-4.5, -11.0, -1.5], rtol=1e-6)
    np.testing.assert_array_equal(mask[:, 1], [1, 1, 0])


def test_gae_drops_the_truncated_step_and_bootstraps_the_one_before():
    # The truncated step t = 1 is dropped (advantage 0, mask 0) and does not leak into t = 0,
    # which bootstraps from the value of its next observation: 1 + 0.5 * 1.0 - 0.5 = 1. The new
    # episode's step t = 2 is unaffected: 3 + 0.5 * 2 - 1.5.
    adv, _, mask = _targets()
    np.testing.assert_allclose(adv[:, 2], [1.0, 0.0, 2.5], rtol=1e-6)
    np.testing.assert_array_equal(mask[:, 2], [1, 0, 1])


def test_ppo_loss_by_hand():
    # Uniform logits over 2 actions: new log-prob log 0.5 for every sample. Behaviour
    # probabilities 0.5, 0.25, 0.8 give ratios 1, 2, 0.625; the third sample is masked out.
    batch = TeamBatch(
        obs={"x": jnp.zeros((3, 1))},
        actions=jnp.array([0, 1, 0]),
        log_prob=jnp.log(jnp.array([0.5, 0.25, 0.8])),
        advantages=jnp.array([1.0, 2.0, -1.0]),
        returns=jnp.array([1.0, 3.0, 100.0]),
        mask=jnp.array([1.0, 1.0, 0.0]),
    )

    def apply_fn(params, obs):
        del params
        n = obs["x"].shape[0]
        return jnp.zeros((n, 2)), jnp.full((n,), 0.5)

    total, metrics = ppo_loss(
        None, batch, apply_fn, clip_epsilon=0.2, value_coef=0.5, entropy_coef=0.01
    )
    # Advantages normalised over the mask: mean 1.5, std 0.5 -> -1, 1.
    # Surrogates: min(1 * -1, 1 * -1) = -1; min(2 * 1, 1.2 * 1) = 1.2 -> policy loss -0.1.
    assert float(metrics["policy_loss"]) == pytest.approx(-0.1, abs=1e-5)
    # Value: 0.5 * mean((1 - 0.5)^2, (3 - 0.5)^2) = 0.5 * 3.25.
    assert float(metrics["value_loss"]) == pytest.approx(1.625, rel=1e-6)
    assert float(metrics["entropy"]) == pytest.approx(math.log(2), rel=1e-6)
    # KL estimate mean((r - 1) - log r) = (0 + 1 - log 2) / 2; one of two samples clipped.
    assert float(metrics["approx_kl"]) == pytest.approx((1 - math.log(2)) / 2, rel=1e-5)
    assert float(metrics["clip_fraction"]) == pytest.approx(0.5)
    assert float(total) == pytest.approx(-0.1 + 0.5 * 1.625 - 0.01 * math.log(2), rel=1e-5)
