"""The clipped PPO loss for one team, with incapacitated agents' transitions masked out."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.training.agents.ppo.losses import compute_gae
from flax import struct

from pe_mjx.networks import entropy, log_prob


@struct.dataclass
class TeamBatch:
    """One team's training samples, agents folded into the batch: every leaf is [N, ...]."""

    obs: dict[str, jax.Array]  # normalised observation dict, per sample
    actions: jax.Array  # int32 [N]
    log_prob: jax.Array  # [N] behaviour policy log-probabilities
    advantages: jax.Array  # [N] GAE advantages
    returns: jax.Array  # [N] value targets (advantages + values)
    mask: jax.Array  # [N] 1 for transitions that count, 0 for incapacitated / truncated ones


def team_targets(
    data: dict[str, jax.Array], bootstrap: jax.Array, gamma: float, gae_lambda: float
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Advantages, value targets and loss mask of one team's [T, B, A] rollout (Brax's GAE).

    `data` holds per agent and step: `reward`, `value` (the behaviour critic's), `termination`
    (1 where the agent's trajectory ends: it was incapacitated this step, the episode
    terminated, or it was already down), `truncation` (1 at the time-limit step of an agent still
    valid) and `valid` (1 while the agent was active before the step). `bootstrap` [B, A] is the
    critic's value of the state after the last step.

    A termination cuts the bootstrap and the GAE recursion; a truncated step is dropped from the
    losses (mask 0), and the step before it bootstraps from the value of its next observation, as
    in Brax. Transitions of agents already down (valid 0) are masked out too.
    """
    advantages = compute_gae(
        truncation=data["truncation"],
        termination=data["termination"],
        rewards=data["reward"],
        values=data["value"],
        bootstrap_value=bootstrap,
        lambda_=gae_lambda,
        discount=gamma,
    )[1]
    returns = advantages + data["value"]
    mask = data["valid"] * (1.0 - data["truncation"])
    return advantages, returns, mask


def masked_mean(x: jax.Array, mask: jax.Array) -> jax.Array:
    return jnp.sum(x * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def ppo_loss(
    params: Any,
    batch: TeamBatch,
    apply_fn: Callable[[Any, dict[str, jax.Array]], tuple[jax.Array, jax.Array]],
    clip_epsilon: float,
    value_coef: float,
    entropy_coef: float,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Clipped surrogate + value + entropy loss (Brax's PPO loss, for masked categoricals).

    Args:
      params: the team's network parameters.
      batch: samples of shape [N, ...].
      apply_fn: `(params, obs) -> (logits [N, n_actions], value [N])`.

    Returns:
      (total loss, metrics: policy/value/entropy losses, approximate KL, clip fraction).
    """
    logits, value = apply_fn(params, batch.obs)
    new_log_prob = log_prob(logits, batch.actions)
    mask = batch.mask
    adv = batch.advantages
    adv_mean = masked_mean(adv, mask)
    adv_std = jnp.sqrt(masked_mean((adv - adv_mean) ** 2, mask) + 1e-8)
    adv = (adv - adv_mean) / adv_std
    log_ratio = new_log_prob - batch.log_prob
    ratio = jnp.exp(log_ratio)
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - clip_epsilon, 1 + clip_epsilon) * adv)
    policy_loss = -masked_mean(surrogate, mask)
    value_loss = 0.5 * masked_mean((batch.returns - value) ** 2, mask)
    entropy_mean = masked_mean(entropy(logits), mask)
    total = policy_loss + value_coef * value_loss - entropy_coef * entropy_mean
    metrics = {
        "policy_loss": policy_loss,
        "value_loss": value_loss,
        "entropy": entropy_mean,
        "approx_kl": masked_mean((ratio - 1) - log_ratio, mask),
        "clip_fraction": masked_mean((jnp.abs(ratio - 1) > clip_epsilon).astype(jnp.float32), mask),
    }
    return total, metrics
