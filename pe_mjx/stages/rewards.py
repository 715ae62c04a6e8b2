"""Reward terms of a step, paper eqs. (3) and (4) plus our evader flee shaping, by name.

Terms are dicts keyed by `names.REWARD_TERMS` (team -> term -> per-agent values); a team's reward
is the sum of its terms in that order, for the agents active before the step.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from pe_mjx.config import EnvConfig
from pe_mjx.names import REWARD_TERMS, TEAMS
from pe_mjx.stages.geometry import Geometry, per_agent, same_team

Terms = dict[str, dict[str, jax.Array]]
"""team -> term name -> [A] (the team's agents)."""


def collision_reward(gap: jax.Array, collision: float, danger: float) -> jax.Array:
    """f_c of paper III-C: r_c at contact, r_c (d - x) / (d + x) inside d_danger, else 0."""
    inside = collision * (danger - gap) / (danger + jnp.maximum(gap, 0.0))
    return jnp.where(gap <= 0, collision, jnp.where(gap <= danger, inside, 0.0))


def zero_terms(config: EnvConfig) -> Terms:
    """Every term of `names.REWARD_TERMS`, zero (a fresh episode's)."""
    return {
        t: {name: jnp.zeros(config.team(t).num_agents) for name in REWARD_TERMS[t]} for t in TEAMS
    }


def paper_terms(
    config: EnvConfig,
    geom: Geometry,
    active: jax.Array,
    capture_pairs: jax.Array,
    obstacles: jax.Array,
) -> Terms:
    """Every term of eqs. (3) and (4), per agent, before masking by who was active.

    `geom`: the `Geometry` of the new positions; `active` bool [N] after the step's events;
    `capture_pairs` bool [P, E] (`Events.capture_pairs`); `obstacles` [K, 3]. All terms but the
    evaders' `flee` (`flee_term`).
    """
    rc = config.reward
    p = config.pursuer.num_agents
    n = p + config.evader.num_agents
    r = jnp.asarray(per_agent(config, "radius"))

    def fc(gap):
        return collision_reward(gap, rc.collision, rc.danger_distance)

    wall = fc(config.arena.radius - geom.norm - r)
    if config.arena.num_obstacles:
        obstacle = jnp.sum(fc(geom.obs_dist - r[:, None] - obstacles[None, :, 2]), axis=1)
    else:
        obstacle = jnp.zeros(n)
    dist = geom.dist
    pair_fc = fc(dist - r[:, None] - r[None, :])
    not_self = ~jnp.eye(n, dtype=bool)
    teammate = jnp.sum(jnp.where(same_team(config) & not_self, pair_fc, 0.0), axis=1)
    # Pursuer-evader terms, f_p of eq. (3).
    evader_active = active[None, p:]
    shaping = rc.pursuit_scale / jnp.maximum(dist[:p, p:], rc.capture_distance)
    shaping = jnp.where(evader_active, shaping, 0.0)
    if rc.pursuit_nearest is not None and rc.pursuit_nearest < n - p:
        shaping = jax.lax.top_k(shaping, rc.pursuit_nearest)[0]  # the nearest: largest 1/d
    pursuit = jnp.sum(shaping, axis=1)
    capture = jnp.sum(jnp.where(capture_pairs, rc.capture, 0.0), axis=1)
    inactive_other = ~evader_active & ~capture_pairs
    pursuer_opp = jnp.sum(jnp.where(inactive_other, pair_fc[:p, p:], 0.0), axis=1)
    opp_danger = rc.opponent_danger_distance
    if opp_danger is not None and opp_danger != rc.danger_distance:
        gap_ep = dist[p:, :p] - r[p:, None] - r[None, :p]
        evader_opp = jnp.sum(collision_reward(gap_ep, rc.collision, opp_danger), axis=1)
    else:
        evader_opp = jnp.sum(pair_fc[p:, :p], axis=1)
    alive = jnp.where(active[p:], rc.evader_alive, 0.0)
    return {
        "pursuer": {
            "wall": wall[:p],
            "obstacle": obstacle[:p],
            "teammate": teammate[:p],
            "pursuit": pursuit,
            "capture": capture,
            "opponent": pursuer_opp,
        },
        "evader": {
            "wall": wall[p:],
            "obstacle": obstacle[p:],
            "teammate": teammate[p:],
            "opponent": evader_opp,
            "alive": alive,
        },
    }


def flee_term(
    config: EnvConfig, old_pos: jax.Array, pos: jax.Array, was_active: jax.Array
) -> jax.Array:
    """Potential-based evader shaping (ours, not the paper's): `reward.evader_flee` times the
    change of Phi = min(distance to the nearest pursuer active before the step, flee_range).

    Moving away from the nearest pursuer pays at once; a potential difference leaves the optimal
    policy unchanged (Ng, Harada and Russell, 1999). Positions [N, 2], `was_active` bool [N];
    returns [E].
    """
    rc, p = config.reward, config.pursuer.num_agents
    if rc.evader_flee == 0.0:
        return jnp.zeros(config.evader.num_agents)

    def potential(x: jax.Array) -> jax.Array:
        d = jnp.linalg.norm(x[p:, None, :] - x[None, :p, :], axis=-1)  # [E, P]
        d = jnp.where(was_active[None, :p], d, jnp.inf)
        return jnp.minimum(jnp.min(d, axis=1), rc.flee_range)

    return rc.evader_flee * (potential(pos) - potential(old_pos))


def reward_terms(
    config: EnvConfig,
    geom: Geometry,
    old_pos: jax.Array,
    pos: jax.Array,
    was_active: jax.Array,
    active: jax.Array,
    capture_pairs: jax.Array,
    obstacles: jax.Array,
) -> Terms:
    """All of `names.REWARD_TERMS`: `paper_terms` and the evaders' `flee_term`."""
    terms = paper_terms(config, geom, active, capture_pairs, obstacles)
    terms["evader"]["flee"] = flee_term(config, old_pos, pos, was_active)
    return terms


def team_rewards(terms: Terms, valid: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """team -> [A]: the sum of its terms (in `names.REWARD_TERMS` order), 0 where not `valid`."""
    return {
        t: jnp.where(valid[t], sum(terms[t][name] for name in REWARD_TERMS[t]), 0.0) for t in TEAMS
    }


__all__ = [
    "Terms",
    "collision_reward",
    "flee_term",
    "paper_terms",
    "reward_terms",
    "team_rewards",
    "zero_terms",
]
