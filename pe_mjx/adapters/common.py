"""What both adapters share: agent names and the flat layout of a team's observation."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from pe_mjx import names
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.names import TEAMS

# The order in which a team's observation dict is flattened; `action_mask` is never part of the
# vector (each adapter hands it over on its own). Keys the env may add later follow, sorted.
OBSERVATION_KEYS = tuple(k for k in names.OBSERVATION_KEYS if k != "action_mask")


def agent_names(env: PursuitEvasionEnv) -> dict[str, list[str]]:
    """{"pursuer": ["pursuer_0", ...], "evader": ["evader_0", ...]}, in the env's agent order."""
    return {t: [f"{t}_{i}" for i in range(env.config.team(t).num_agents)] for t in TEAMS}


def _keys(obs: dict) -> list[str]:
    known = [k for k in OBSERVATION_KEYS if k in obs]
    return known + sorted(k for k in obs if k not in OBSERVATION_KEYS and k != "action_mask")


def observation_layout(env: PursuitEvasionEnv, team: str) -> dict[str, tuple[slice, tuple]]:
    """Where each entry of one agent's observation dict lies in its flat vector.

    Returns {key: (slice into the vector, per-agent shape)}, e.g. for a pursuer of 2-1-1:
    own (5,), teammates (1, 6), opponents (1, 6), obstacles (1, 4), then the three entity masks
    (1,), (1,), (1,) as 0/1. `x[sl].reshape(shape)` recovers an entry.
    """
    shapes = jax.eval_shape(env.reset, jax.random.key(0)).obs[team]
    layout, start = {}, 0
    for key in _keys(shapes):
        shape = tuple(shapes[key].shape[1:])  # drop the agent axis
        size = math.prod(shape)
        layout[key] = (slice(start, start + size), shape)
        start += size
    return layout


def flatten_observation(team_obs: dict[str, jax.Array]) -> jax.Array:
    """A team's observation dict -> float32 [A, D], entries in `OBSERVATION_KEYS` order.

    Args:
      team_obs: `state.obs[team]`, each entry [A, ...] (bool masks become 0/1).
    """
    parts = [team_obs[k].reshape(team_obs[k].shape[0], -1) for k in _keys(team_obs)]
    return jnp.concatenate([p.astype(jnp.float32) for p in parts], axis=-1)
