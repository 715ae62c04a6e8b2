"""Heading-frame observations (SPEC 2.5), per team: own state, teammates, opponents, obstacles."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from pe_mjx.config import EnvConfig
from pe_mjx.names import ABSENT, OBSTACLE_FEATURES, TEAMS, other_team
from pe_mjx.stages.geometry import Geometry, bearing, drop_diagonal, per_agent, to_heading
from pe_mjx.stages.masks import MaskTable, action_mask
from pe_mjx.stages.world import World

Observation = dict[str, dict[str, jax.Array]]
"""team -> {"own", "teammates", "opponents", "obstacles", their masks, "action_mask"}."""


def team_slices(config: EnvConfig) -> dict[str, slice]:
    """team -> its agents' slice of the N agents (pursuers first)."""
    p, e = config.pursuer.num_agents, config.evader.num_agents
    return {"pursuer": slice(0, p), "evader": slice(p, p + e)}


def entity_observations(config: EnvConfig, world: World, geom: Geometry) -> Observation:
    """Every observation block but the action mask, per team.

    For a team of A agents (P pursuers, E evaders, K obstacles): `own` [A, 5] (downed flag,
    distance from the centre / R, bearing of the centre, forward speed / v_max); `teammates`
    [A, A - 1, 6] and `opponents` [A, A', 6] (downed flag, distance / R, bearing, velocity in the
    heading frame / the observer's v_max); `obstacles` [A, K, 4] (distance / R, bearing,
    radius / R); and their masks, False only for entities absent from the episode. `geom` is the
    `Geometry` of the world's poses.
    """
    R = config.arena.radius
    n, k = config.pursuer.num_agents + config.evader.num_agents, config.arena.num_obstacles
    c, s = geom.cos, geom.sin
    vmax = jnp.asarray(per_agent(config, "max_speed"))
    flag = (~world.active).astype(jnp.float32)

    cos_o, sin_o = bearing(geom.origin_hx, geom.origin_hy, geom.norm)
    speed = world.vel[:, 0] * c + world.vel[:, 1] * s
    own = jnp.stack([flag, geom.norm / R, cos_o, sin_o, speed / vmax], axis=-1)

    d = geom.dist
    cos_b, sin_b = bearing(geom.hx, geom.hy, d)
    vx, vy = to_heading(c[:, None], s[:, None], world.vel[None, :, 0], world.vel[None, :, 1])
    agent_features = (
        jnp.broadcast_to(flag[None, :], d.shape),
        d / R,
        cos_b,
        sin_b,
        vx / vmax[:, None],
        vy / vmax[:, None],
    )  # each [N, N]: row i observes agent j

    def agents(rows: slice, cols: slice) -> jax.Array:
        return jnp.stack([f[rows, cols] for f in agent_features], axis=-1)

    d_k = geom.obs_dist
    cos_k, sin_k = bearing(geom.obs_hx, geom.obs_hy, d_k)
    obst = jnp.stack(
        [d_k / R, cos_k, sin_k, jnp.broadcast_to(world.obstacles[None, :, 2] / R, d_k.shape)],
        axis=-1,
    ).reshape(n, k, OBSTACLE_FEATURES)

    # Entities absent from the episode (`min_agents`, `min_obstacles`) are masked out for every
    # observer; all others are seen, incapacitated agents included (flag 1).
    seen = jnp.broadcast_to((world.cause != ABSENT)[None, :], (n, n))
    seen_obstacles = jnp.broadcast_to((world.obstacles[:, 2] > 0)[None, :], (n, k))
    slices = team_slices(config)
    obs = {}
    for team in TEAMS:
        sl, other = slices[team], slices[other_team(team)]
        mates = drop_diagonal(agents(sl, sl))
        opps = agents(sl, other)
        obs[team] = {
            "own": own[sl],
            "teammates": mates,
            "opponents": opps,
            "obstacles": obst[sl],
            "teammate_mask": drop_diagonal(seen[sl, sl]),
            "opponent_mask": seen[sl, other],
            "obstacle_mask": seen_obstacles[sl],
        }
    return obs


def action_masks(
    config: EnvConfig, tables: dict[str, MaskTable], world: World, geom: Geometry
) -> dict[str, jax.Array]:
    """team -> bool [A, n_actions]: `masks.action_mask` for each team's rows of `geom`."""
    out = {}
    for team, sl in team_slices(config).items():
        out[team] = action_mask(
            config,
            tables[team],
            geom.origin_hx[sl],
            geom.origin_hy[sl],
            geom.obs_hx[sl],
            geom.obs_hy[sl],
            world.obstacles,
        )
    return out


def observe(
    config: EnvConfig, tables: dict[str, MaskTable], world: World, geom: Geometry
) -> Observation:
    """`entity_observations` with each team's `action_mask` added."""
    obs = entity_observations(config, world, geom)
    for team, mask in action_masks(config, tables, world, geom).items():
        obs[team]["action_mask"] = mask
    return obs


__all__ = ["Observation", "action_masks", "entity_observations", "observe", "team_slices"]
