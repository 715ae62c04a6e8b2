"""Play-time policies from networks: observation statistics + actor-critic -> `(obs, rng) -> a`.

The trainer, the checkpoint loader, the evaluator and the viewer all act through these, so a
policy plays the same wherever it runs. Observation normalisation is Brax's `running_statistics`,
one statistic per entity type over its feature axis (independent of entity counts).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.training.acme import running_statistics

from pe_mjx.networks import MASK_KEYS, greedy_actions, sample_actions
from pe_mjx.policies import Policy

ENTITY_KEYS = ("own", "teammates", "opponents", "obstacles")
ENTITY_MASKS = MASK_KEYS


def init_normalizer(obs: dict[str, jax.Array]) -> dict[str, Any]:
    """One running statistic per entity type, over its feature axis only."""
    return {
        k: running_statistics.init_state(jax.ShapeDtypeStruct(obs[k].shape[-1:], jnp.float32))
        for k in ENTITY_KEYS
    }


def normalize_obs(obs: dict[str, jax.Array], normalizer: dict[str, Any]) -> dict[str, jax.Array]:
    out = dict(obs)
    for k in ENTITY_KEYS:
        out[k] = running_statistics.normalize(obs[k], normalizer[k], max_abs_value=5.0)
    return out


def update_normalizer(
    normalizer: dict[str, Any], obs: dict[str, jax.Array], valid: jax.Array
) -> dict[str, Any]:
    """Updates each entity type's statistics with the observations of valid agents.

    Args:
      obs: observation dict with leading dims [..., A] (e.g. [T, B, A]).
      valid: bool [..., A], the agents whose transitions count.
    """
    new = dict(normalizer)
    for k in ENTITY_KEYS:
        x = obs[k]
        if x.size == 0:
            continue
        weights = valid.astype(jnp.float32)
        if k in ENTITY_MASKS:
            weights = weights[..., None] * obs[ENTITY_MASKS[k]]
        new[k] = running_statistics.update(normalizer[k], x, weights=weights)
    return new


def policy_apply(network: Any, deterministic: bool = False) -> Callable[..., jax.Array]:
    """`apply(variables, obs, rng) -> actions` with the learned state as an argument.

    `variables` is `{"params": ..., "normalizer": ...}`. Unlike `learned_policy`, which closes
    over them, a jitted caller takes them as inputs, so one compile serves every policy of the
    same network shape (the evaluator compiles once per shape, not once per pairing).
    """

    def apply(variables: dict[str, Any], obs: dict[str, jax.Array], rng: jax.Array) -> jax.Array:
        logits, _ = network.apply(variables["params"], normalize_obs(obs, variables["normalizer"]))
        return greedy_actions(logits) if deterministic else sample_actions(logits, rng)

    return apply


def learned_policy(
    network: Any, params: Any, normalizer: dict[str, Any], deterministic: bool = False
) -> Policy:
    """A jittable `(obs, rng) -> actions` from network parameters and observation statistics.

    `obs` is one team's observation dict with any leading dims ([A, ...] for one arena).
    """
    apply = policy_apply(network, deterministic)
    variables = {"params": params, "normalizer": normalizer}

    def policy(obs: dict[str, jax.Array], rng: jax.Array) -> jax.Array:
        return apply(variables, obs, rng)

    return policy
