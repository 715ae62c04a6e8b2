"""Incapacitation events of a step (SPEC 2.3), in order: wall, obstacle, capture, collision."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from pe_mjx.config import EnvConfig
from pe_mjx.names import CAPTURE, OBSTACLE, OPPONENT, TEAMMATE, WALL
from pe_mjx.stages.geometry import Geometry, per_agent, same_team


@struct.dataclass
class Events:
    """Who a step incapacitated, and why; P pursuers, E evaders, N = P + E agents."""

    active: jax.Array  # bool [N] still active after the step
    cause: jax.Array  # int32 [N]: this step's cause for the agents it downed, else 0
    capture_pairs: jax.Array  # bool [P, E]: pursuer i captured evader j this step
    new_captures: jax.Array  # int32 [N]: pursuer -> evaders it captured; evader -> 1 if captured


def events(
    config: EnvConfig, geom: Geometry, was_active: jax.Array, obstacles: jax.Array
) -> Events:
    """SPEC 2.3 in order: wall, obstacle, capture (an active pursuer and an active evader within
    `capture_eps`), then any other touching pair involving an agent still active.

    `geom`: the `Geometry` of the new positions; `was_active` bool [N]; `obstacles` [K, 3].
    """
    p = config.pursuer.num_agents
    n = p + config.evader.num_agents
    r = jnp.asarray(per_agent(config, "radius"))
    cause = jnp.zeros(n, dtype=jnp.int32)
    active = was_active
    # 1. wall
    hit = active & (geom.norm + r >= config.arena.radius)
    cause, active = jnp.where(hit, WALL, cause), active & ~hit
    # 2. obstacles
    if config.arena.num_obstacles:
        gap_obs = geom.obs_dist - r[:, None] - obstacles[None, :, 2]
        hit = active & jnp.any(gap_obs <= 0, axis=1)
        cause, active = jnp.where(hit, OBSTACLE, cause), active & ~hit
    # 3. capture: active pursuer and active evader within epsilon
    dist = geom.dist
    pairs = (dist[:p, p:] <= config.capture_eps) & active[:p, None] & active[None, p:]
    captured = jnp.concatenate([jnp.any(pairs, axis=1), jnp.any(pairs, axis=0)])
    cause, active = jnp.where(captured, CAPTURE, cause), active & ~captured
    new_captures = jnp.concatenate(
        [jnp.sum(pairs, axis=1), jnp.any(pairs, axis=0).astype(jnp.int32)]
    ).astype(jnp.int32)
    # 4. any other touching pair involving an agent still active
    gap = dist - r[:, None] - r[None, :]
    touching = (gap <= 0) & ~jnp.eye(n, dtype=bool)
    mates = same_team(config)
    hit_team = active & jnp.any(touching & mates, axis=1)
    hit_opp = active & jnp.any(touching & ~mates, axis=1)
    cause = jnp.where(hit_team, TEAMMATE, jnp.where(hit_opp, OPPONENT, cause))
    active = active & ~(hit_team | hit_opp)
    return Events(active=active, cause=cause, capture_pairs=pairs, new_captures=new_captures)


__all__ = ["Events", "events"]
