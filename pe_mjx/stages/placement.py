"""A fresh arena for `reset`: random sequential placement of obstacles, then agents, and (with
`min_agents` / `min_obstacles`) which of them take part in the episode."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from pe_mjx.config import EnvConfig
from pe_mjx.names import PARK_DISTANCE
from pe_mjx.stages.geometry import per_agent


@struct.dataclass
class Placement:
    """Obstacles and agent poses of a fresh arena; K obstacles, N agents (pursuers first)."""

    obstacles: jax.Array  # [K, 3] x, y, radius (0 for an absent obstacle)
    pos: jax.Array  # [N, 2]
    yaw: jax.Array  # [N]
    ok: jax.Array  # bool []: every entity found a candidate with the required clearance
    present: jax.Array  # bool [N]: False for agents absent from this episode (`min_agents`)


def draw_counts(config: EnvConfig, rng: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Which agents (bool [N], pursuers first) and obstacles (bool [K]) take part in an episode:
    the first n of each team and the first k obstacles, n and k uniform in [min, max] of the
    config (`TeamConfig.min_agents`, `ArenaConfig.min_obstacles`; None: all)."""
    ranges = (
        (config.pursuer.min_agents, config.pursuer.num_agents),
        (config.evader.min_agents, config.evader.num_agents),
        (config.arena.min_obstacles, config.arena.num_obstacles),
    )
    keys = jax.random.split(rng, len(ranges))
    flags = []
    for key, (low, high) in zip(keys, ranges, strict=True):
        count = high if low is None else jax.random.randint(key, (), low, high + 1)
        flags.append(jnp.arange(high) < count)
    return jnp.concatenate(flags[:2]), flags[2]


def varies_counts(config: EnvConfig) -> bool:
    """Whether the config draws entity counts per episode."""
    lows = (config.pursuer.min_agents, config.evader.min_agents, config.arena.min_obstacles)
    return any(low is not None for low in lows)


def place(config: EnvConfig, rng: jax.Array) -> Placement:
    """Obstacles, then agents, each at the first of `spawn_candidates` uniform draws in the disc
    that keeps `spawn_clearance` from everything placed before (the roomiest one if none does).

    `ok` is always true for configs that pass the density check in `EnvConfig`, up to a vanishing
    probability.
    """
    a = config.arena
    k, n = a.num_obstacles, config.pursuer.num_agents + config.evader.num_agents
    total = k + n
    rng_r, rng_yaw, rng_c = jax.random.split(rng, 3)
    obstacle_r = jax.random.uniform(
        rng_r, (k,), minval=a.obstacle_radius_min, maxval=a.obstacle_radius_max
    )
    radii = jnp.concatenate([obstacle_r, jnp.asarray(per_agent(config, "radius"))])
    m = a.spawn_candidates
    u = jax.random.uniform(rng_c, (total, m, 2))
    clear = a.spawn_clearance

    def body(i, carry):
        pos, ok = carry
        r = radii[i]
        rho = (a.radius - r - clear) * jnp.sqrt(u[i, :, 0])
        phi = 2 * jnp.pi * u[i, :, 1]
        cand = jnp.stack([rho * jnp.cos(phi), rho * jnp.sin(phi)], axis=-1)  # [M, 2]
        dist = jnp.linalg.norm(cand[:, None, :] - pos[None, :, :], axis=-1)  # [M, T]
        gap = dist - r - radii[None, :]
        placed = jnp.arange(total) < i
        min_gap = jnp.min(jnp.where(placed[None, :], gap, jnp.inf), axis=1)  # [M]
        good = min_gap >= clear
        choice = jnp.where(jnp.any(good), jnp.argmax(good), jnp.argmax(min_gap))
        pos = pos.at[i].set(cand[choice])
        return pos, ok & jnp.any(good)

    pos0 = jnp.zeros((total, 2))
    pos, ok = jax.lax.fori_loop(0, total, body, (pos0, jnp.ones((), dtype=bool)))
    obstacles = jnp.concatenate([pos[:k], obstacle_r[:, None]], axis=1)
    yaw = jax.random.uniform(rng_yaw, (n,), minval=-jnp.pi, maxval=jnp.pi)
    agents = pos[k:]
    present = jnp.ones(n, dtype=bool)
    if varies_counts(config):
        # Its own key, folded off: a config with fixed counts draws exactly what it always drew.
        present, obstacle_present = draw_counts(config, jax.random.fold_in(rng, 1))
        far = PARK_DISTANCE * a.radius
        park_agents = jnp.stack([far + jnp.arange(n, dtype=jnp.float32), jnp.zeros(n)], -1)
        agents = jnp.where(present[:, None], agents, park_agents)
        park_obstacles = jnp.stack(
            [jnp.zeros(k), far + jnp.arange(k, dtype=jnp.float32), jnp.zeros(k)], -1
        )
        obstacles = jnp.where(obstacle_present[:, None], obstacles, park_obstacles)
    return Placement(obstacles=obstacles, pos=agents, yaw=yaw, ok=ok, present=present)


__all__ = ["PARK_DISTANCE", "Placement", "draw_counts", "place", "varies_counts"]
