"""Learned policies: observation statistics + actor-critic -> a `Policy`.

The trainer, the policy store, the evaluator and the viewer all act through these, so a policy
plays the same wherever it runs (`pe_mjx.policy.resolve` turns a policy spec into one).
Observation normalisation is Brax's `running_statistics`, one statistic per entity type over its
feature axis (independent of entity counts).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.training.acme import running_statistics

from pe_mjx.config import EnvConfig
from pe_mjx.experiment import NetworkConfig
from pe_mjx.names import (
    AGENT_FEATURES,
    ENTITY_KEYS,
    LENGTH_FEATURES,
    MASK_KEYS,
    OBSTACLE_FEATURES,
    OWN_FEATURES,
    other_team,
)
from pe_mjx.networks import greedy_actions, sample_actions
from pe_mjx.policy.core import Policy, team_letter


def dummy_obs(env_config: EnvConfig, team: str) -> dict[str, jax.Array]:
    """Zero observations of one arena with the shapes the env gives `team` (for network init)."""
    a = env_config.team(team).num_agents
    other = env_config.team(other_team(team)).num_agents
    k = env_config.arena.num_obstacles
    n_act = env_config.team(team).num_actions
    return {
        "own": jnp.zeros((a, OWN_FEATURES)),
        "teammates": jnp.zeros((a, a - 1, AGENT_FEATURES)),
        "opponents": jnp.zeros((a, other, AGENT_FEATURES)),
        "obstacles": jnp.zeros((a, k, OBSTACLE_FEATURES)),
        "teammate_mask": jnp.ones((a, a - 1), bool),
        "opponent_mask": jnp.ones((a, other), bool),
        "obstacle_mask": jnp.ones((a, k), bool),
        "action_mask": jnp.ones((a, n_act), bool),
    }


def length_scale(network_config: NetworkConfig, env_config: EnvConfig) -> float | None:
    """The factor from the env's lengths (arena radii) to the network's (`length_unit` metres)
    in the scene `env_config`; None for a network that reads arena radii."""
    unit = network_config.length_unit
    return None if unit is None else env_config.arena.radius / unit


def in_length_unit(obs: dict[str, jax.Array], scale: jax.Array | float) -> dict[str, jax.Array]:
    """`obs` with the neighbour lengths (`names.LENGTH_FEATURES`) multiplied by `scale`."""
    out = dict(obs)
    for key, features in LENGTH_FEATURES.items():
        factor = jnp.ones(obs[key].shape[-1]).at[jnp.asarray(features)].set(scale)
        out[key] = obs[key] * factor
    return out


def network_inputs(obs: dict[str, jax.Array], variables: dict[str, Any]) -> dict[str, jax.Array]:
    """What the network reads: `obs` in its length unit (`variables["length_scale"]`, if any),
    normalised by `variables["normalizer"]`."""
    if "length_scale" in variables:
        obs = in_length_unit(obs, variables["length_scale"])
    return normalize_obs(obs, variables["normalizer"])


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
        if k in MASK_KEYS:
            weights = weights[..., None] * obs[MASK_KEYS[k]]
        new[k] = running_statistics.update(normalizer[k], x, weights=weights)
    return new


def policy_apply(network: Any, deterministic: bool = False) -> Callable[..., jax.Array]:
    """`apply(variables, obs, rng) -> actions` with the learned state as an argument.

    `variables` is `{"params": ..., "normalizer": ...}`, and `"length_scale"` for a network with
    a `length_unit` (`learned_policy` adds it for the scene played). A jitted caller takes them
    as inputs, so one compile serves every policy of the same network shape (the evaluator
    compiles once per shape, not once per pairing).
    """

    def apply(variables: dict[str, Any], obs: dict[str, jax.Array], rng: jax.Array) -> jax.Array:
        logits, _ = network.apply(variables["params"], network_inputs(obs, variables))
        return greedy_actions(logits) if deterministic else sample_actions(logits, rng)

    return apply


def learned_policy(
    team: str,
    network: Any,
    network_config: NetworkConfig,
    variables: dict[str, Any],
    source: str = "training",
    label: str | None = None,
    deterministic: bool = False,
    env_config: EnvConfig | None = None,
    **fields: Any,
) -> Policy:
    """The `Policy` of a network with its variables ({"params", "normalizer"}).

    Args:
      source: where it came from (a run directory; "training" for the trainer's current state).
      label: the paper's label; by default "P_MIX" etc.
      env_config: the scene it plays; needed for a network with a `length_unit` (whose inputs
        depend on the arena radius).
      fields: further `Policy` fields (`shape_key`, `note`).
    """
    encoder = network_config.encoder
    if network_config.length_unit is not None:
        if env_config is None:
            raise ValueError("a policy with a length_unit needs the env config of its scene")
        scale = length_scale(network_config, env_config)
        variables = {**variables, "length_scale": jnp.asarray(scale, jnp.float32)}
    return Policy(
        team=team,
        source=source,
        label=label or f"{team_letter(team)}_{encoder.upper()}",
        method=encoder,
        apply=policy_apply(network, deterministic),
        variables=variables,
        network=network,
        network_config=network_config,
        deterministic=deterministic,
        attention_apply=(
            attention_policy_apply(network, deterministic) if encoder == "mix" else None
        ),
        **fields,
    )


def attention_policy_apply(
    network: Any, deterministic: bool = False
) -> Callable[..., tuple[jax.Array, jax.Array]]:
    """`apply(variables, obs, rng) -> (actions, attention)` of a MIX network, for the viewer (a
    MIX `Policy`'s `attention_apply`): each agent's own-token attention over its tokens, mean over
    heads, float [A, M]; actions int32 [A]."""

    def apply(variables: dict[str, Any], obs: dict[str, jax.Array], rng: jax.Array):
        inputs = network_inputs(obs, variables)
        (logits, _), inter = network.apply(variables["params"], inputs, mutable=["intermediates"])
        weights = inter["intermediates"]["encoder"]["attention"][0]  # [A, H, M]
        actions = greedy_actions(logits) if deterministic else sample_actions(logits, rng)
        return actions.astype(jnp.int32), jnp.mean(weights, axis=-2)

    return apply
