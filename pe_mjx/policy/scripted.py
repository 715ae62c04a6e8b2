"""Hand-written policies for both teams (scripted pursuit and evasion, random) and a registry.

`make_policy` wraps one in the package's `Policy` type. The functions themselves have the signature
a learned policy has::

    policy(obs: dict[str, jax.Array], rng: jax.Array) -> int32 [A]

where ``obs`` is ONE team's observation dict for one arena (``state.obs[team]``, SPEC 2.5):
``own [A, 5]``, ``teammates [A, T, 6]``, ``opponents [A, O, 6]``, ``obstacles [A, K, 4]``, the
validity masks ``teammate_mask [A, T]``, ``opponent_mask [A, O]``, ``obstacle_mask [A, K]`` and
``action_mask bool [A, n_actions]``. Policies are pure and jittable; ``jax.vmap`` them over arenas.
They are decentralised: each agent uses only its own observation row plus static config (arena
radius to undo the distance normalisation, its team's action table, the control step), and they only
ever return actions whose ``action_mask`` entry is True.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.config import EnvConfig
from pe_mjx.names import BUILTIN_POLICIES, TEAMS
from pe_mjx.policy.core import Policy, PolicyFn, builtin_policy
from pe_mjx.stages.dynamics import action_table, arc_offsets

# ----------------------------------------------------------------------------- geometry helpers


def _entities(
    feats: jax.Array, valid: jax.Array, arena_radius: float, max_speed: float
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Decodes other-agent features of one observer.

    Args:
      feats: [M, 6] rows ``[g, d/R, cos, sin, vx/vmax, vy/vmax]`` in the observer's heading frame.
      valid: bool [M] entity-validity mask (padding is False).
      arena_radius: R, the distance normaliser.
      max_speed: the observer's own v_max, the velocity normaliser.

    Returns:
      pos [M, 2] and vel [M, 2] in metres (per second) in the heading frame, and ``active`` bool
      [M] (valid and flag g = 0).
    """
    dist = feats[:, 1] * arena_radius
    pos = dist[:, None] * feats[:, 2:4]
    vel = feats[:, 4:6] * max_speed
    active = valid & (feats[:, 0] < 0.5)
    return pos, vel, active


class _Seen(NamedTuple):
    """What one agent observes of the other agents, decoded by `_entities`: positions and
    velocities [M, 2] in its heading frame, ``on`` (active) and ``valid`` bool [M], for its
    teammates (M = T) and its opponents (M = O)."""

    mate_pos: jax.Array
    mate_vel: jax.Array
    mate_on: jax.Array
    mate_valid: jax.Array
    opp_pos: jax.Array
    opp_vel: jax.Array
    opp_on: jax.Array
    opp_valid: jax.Array


def _seen(
    mates: jax.Array,
    mate_valid: jax.Array,
    opps: jax.Array,
    opp_valid: jax.Array,
    arena_radius: float,
    max_speed: float,
) -> _Seen:
    """`_entities` of the teammate rows ``[T, 6]`` and the opponent rows ``[O, 6]``."""
    mate_pos, mate_vel, mate_on = _entities(mates, mate_valid, arena_radius, max_speed)
    opp_pos, opp_vel, opp_on = _entities(opps, opp_valid, arena_radius, max_speed)
    return _Seen(mate_pos, mate_vel, mate_on, mate_valid, opp_pos, opp_vel, opp_on, opp_valid)


def _norm(v: jax.Array) -> jax.Array:
    """Length of planar vectors ``v [..., 2]``: [...].

    Written per component, not as ``jnp.linalg.norm(v, axis=-1)``: XLA's CPU backend then fuses
    it into one vectorised loop instead of reducing a size-2 minor axis, which makes the scripted
    policies 3-3.5x faster (`tools/bench_eval.py`). The two differ in the last bit of some
    distances (how XLA rounds the sum of squares), so an argmin between two equally good actions
    can flip: 0.2-0.4% of the scripted actions over 60 steps of 32 arenas (2026-12-02)."""
    return jnp.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1])


def _gap(points: jax.Array, centres: jax.Array, radii: jax.Array | float) -> jax.Array:
    """Surface gap between circles at ``points [..., 2]`` and ``centres [M, 2]``: [..., M]."""
    d = _norm(points[..., None, :] - centres)
    return d - radii


def _per_agent(one: Callable[..., jax.Array], fields: tuple[str, ...]) -> PolicyFn:
    """A team policy from `one(*obs[f] for f in fields, action_mask) -> action` of one agent,
    vmapped over the team's agents (scripted policies ignore the rng)."""
    batched = jax.vmap(one)

    def policy(obs: dict[str, jax.Array], rng: jax.Array) -> jax.Array:
        del rng
        return batched(*(obs[f] for f in fields), obs["action_mask"])

    return policy


def _masked_argmin(cost: jax.Array, action_mask: jax.Array) -> jax.Array:
    """argmin of ``cost [n]`` over one agent's valid actions (``action_mask`` bool [n]): int32."""
    return jnp.argmin(jnp.where(action_mask, cost, jnp.inf)).astype(jnp.int32)


def _end_points(config: EnvConfig, team: str, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each action's arc in the heading frame at ``times``: ([n, len(times), 2], |omega| [n])."""
    v, w = action_table(config.team(team))
    return arc_offsets(v, w, np.asarray(times, dtype=np.float64)), np.abs(w)


# ----------------------------------------------------------------------------- scripted pursuer


def _assign_target(seen: _Seen, d_self: jax.Array, crowd_penalty: float) -> jax.Array:
    """The evader a pursuer targets (int index into [O]): the lowest distance ``d_self [O]``
    plus ``crowd_penalty`` per teammate beyond the quota that is closer to that evader."""
    d_mates = _norm(seen.opp_pos[None, :, :] - seen.mate_pos[:, None, :])  # [T, O]
    closer = jnp.sum(seen.mate_on[:, None] & (d_mates < d_self[None, :]), axis=0)  # [O]
    n_pursuers = 1 + jnp.sum(seen.mate_on)
    n_evaders = jnp.maximum(jnp.sum(seen.opp_on), 1)
    quota = (n_pursuers + n_evaders - 1) // n_evaders
    excess = jnp.maximum(closer - (quota - 1), 0)
    score = jnp.where(seen.opp_on, d_self + crowd_penalty * excess, jnp.inf)
    return jnp.argmin(score)


def _intrusion(
    ends: jax.Array, seen: _Seen, dt: float, r_self: float, r_opp: float, danger: float
) -> jax.Array:
    """How deep, in danger distances, each action's end point ``ends [n, 2]`` gets into the
    danger zone of a teammate (moving, one step ahead) or of an incapacitated evader (staying
    put): [n, T + O]."""
    mate_next = jnp.where(seen.mate_on[:, None], seen.mate_pos + seen.mate_vel * dt, seen.mate_pos)
    centres = jnp.concatenate([mate_next, seen.opp_pos], axis=0)
    radii = jnp.concatenate(
        [
            jnp.full(seen.mate_pos.shape[:1], r_self + r_self),
            jnp.full(seen.opp_pos.shape[:1], r_self + r_opp),
        ]
    )
    repel = jnp.concatenate([seen.mate_valid, seen.opp_valid & ~seen.opp_on])
    gaps = _gap(ends, centres, radii)  # [n, T + O]
    return jnp.where(repel, jnp.maximum(danger - gaps, 0.0) / danger, 0.0)


def scripted_pursuer(
    config: EnvConfig,
    *,
    crowd_penalty: float | None = None,
    lead_time: float = 1.0,
    danger_distance: float | None = None,
    danger_weight: float = 4.0,
) -> PolicyFn:
    """Target assignment plus pure pursuit through the action mask.

    Each pursuer, from its own observation only:

    1. **Assignment.** For every active evader e it counts the active teammates that are closer to e
       than itself (teammate-to-evader vectors follow from the relative positions it observes). With
       quota ``q = ceil(active pursuers / active evaders)``, every teammate beyond ``q - 1`` that is
       closer adds ``crowd_penalty`` metres to e's score; the score is the distance to e plus that
       penalty, and the pursuer targets the evader with the lowest score. The pursuers spread over
       the evaders without talking to each other.
    2. **Pursuit.** The target point is the evader's position led by its observed velocity for
       ``min(distance / v_max, lead_time)`` seconds. Among the actions allowed by
       ``action_mask``, the pursuer takes the one whose arc end point after ``control_dt`` lies
       closest to the target, plus ``danger_weight`` times how deep (in danger distances) the end
       point gets into the danger zone of a teammate (predicted one step ahead by its observed
       velocity) or of an incapacitated agent (a static obstacle).
    3. With no active evader it stops (the valid action with the least speed and turn).

    Args:
      config: the game; uses the arena radius, the pursuer team's action table and ``control_dt``.
      crowd_penalty: metres added per excess closer teammate; default: the arena radius.
      lead_time: cap, in seconds, of the target's velocity lead.
      danger_distance: gap in metres below which teammates repel; default: the reward's
        ``danger_distance``.
      danger_weight: weight of the repulsion, in metres per danger-distance of intrusion.

    Returns:
      ``policy(obs, rng) -> int32 [P]`` (``rng`` is unused: the policy is deterministic).
    """
    R = config.arena.radius
    team = config.pursuer
    vmax = team.max_speed
    dt = config.control_dt
    r_self, r_opp = team.radius, config.evader.radius
    crowd = R if crowd_penalty is None else crowd_penalty
    danger = config.reward.danger_distance if danger_distance is None else danger_distance
    ends_np, abs_w = _end_points(config, "pursuer", [dt])
    ends = jnp.asarray(ends_np[:, 0])  # [n, 2]
    v_np, _ = action_table(team)
    stop_cost = jnp.asarray(v_np + 1e-3 * abs_w)  # least motion first

    def one(own, mates, mate_valid, opps, opp_valid, action_mask):
        del own
        seen = _seen(mates, mate_valid, opps, opp_valid, R, vmax)
        d_self = _norm(seen.opp_pos)  # [O]
        target_id = _assign_target(seen, d_self, crowd)
        has_target = jnp.any(seen.opp_on)
        # Pure pursuit to the target point, led by the target's velocity.
        lead = jnp.minimum(d_self[target_id] / vmax, lead_time)
        target = seen.opp_pos[target_id] + seen.opp_vel[target_id] * lead
        chase = _norm(ends - target)  # [n]
        intrusion = _intrusion(ends, seen, dt, r_self, r_opp, danger)
        cost = chase + danger_weight * jnp.sum(intrusion, axis=-1)
        cost = jnp.where(has_target, cost, stop_cost)
        return _masked_argmin(cost, action_mask)

    return _per_agent(one, ("own", "teammates", "teammate_mask", "opponents", "opponent_mask"))


# ----------------------------------------------------------------------------- scripted evader

_FLOOR = 0.005
"""Metres: every distance of the evader's potential is floored at this, so touching costs a lot
but stays finite."""


def _inverse(gap: jax.Array, power: float = 1.0) -> jax.Array:
    return 1.0 / jnp.maximum(gap, _FLOOR) ** power


class _Walls(NamedTuple):
    """The static surroundings of one evader in its heading frame: the arena's centre [2] and
    radius (metres), the obstacles' centres [K, 2], radii [K] and validity bool [K]."""

    centre: jax.Array
    radius: float
    obst_pos: jax.Array
    obst_radius: jax.Array
    obst_valid: jax.Array


def _walls(own: jax.Array, obst: jax.Array, obst_valid: jax.Array, arena_radius: float) -> _Walls:
    """Decodes the wall from the own features ``own [5]`` (r_o, theta_o) and the obstacle rows
    ``obst [K, 4]``."""
    centre = own[1] * arena_radius * own[2:4]
    obst_pos = obst[:, 0:1] * arena_radius * obst[:, 1:3]  # [K, 2]
    obst_radius = obst[:, 3] * arena_radius
    return _Walls(centre, arena_radius, obst_pos, obst_radius, obst_valid)


class _Weights(NamedTuple):
    """The scripted evader's potential: the pursuer term ``pursuer / d^pursuer_power``, the
    weights of the ``w / gap`` terms (metres), and both teams' body radii (metres)."""

    pursuer: float
    pursuer_power: float
    wall: float
    obstacle: float
    teammate: float
    r_self: float
    r_opp: float


def _potential(
    x: jax.Array,
    opp_t: jax.Array,
    mate_t: jax.Array,
    reach_t: jax.Array,
    seen: _Seen,
    walls: _Walls,
    w: _Weights,
) -> jax.Array:
    """The potential at every action's arc point ``x [n, 2]`` at one look-ahead time, with the
    pursuers at ``opp_t [O, 2]`` (discs of radius ``reach_t``) and the teammates at
    ``mate_t [T, 2]``: [n]."""
    d_opp = _norm(x[:, None, :] - opp_t)  # [n, O]
    chase = w.pursuer * _inverse(d_opp - reach_t, w.pursuer_power)
    downed = w.teammate * _inverse(d_opp - w.r_self - w.r_opp)
    opp_u = jnp.where(seen.opp_on, chase, jnp.where(seen.opp_valid, downed, 0.0))
    mate_u = jnp.where(seen.mate_valid, w.teammate * _inverse(_gap(x, mate_t, 2 * w.r_self)), 0)
    wall_gap = walls.radius - _norm(x - walls.centre) - w.r_self
    obst_gap = _gap(x, walls.obst_pos, walls.obst_radius + w.r_self)
    obst_u = jnp.where(walls.obst_valid, w.obstacle * _inverse(obst_gap), 0.0)
    return (
        jnp.sum(opp_u, -1) + jnp.sum(mate_u, -1) + jnp.sum(obst_u, -1) + w.wall * _inverse(wall_gap)
    )


def _unsafe(step_ends: jax.Array, seen: _Seen, dt: float, w: _Weights, margin: float) -> jax.Array:
    """1e9 for each action whose next-step end point ``step_ends [n, 2]`` comes within
    ``margin`` of a teammate (extrapolated by its velocity) or of a downed pursuer, else 0: [n]."""
    mate_next = seen.mate_pos + jnp.where(seen.mate_on[:, None], seen.mate_vel, 0.0) * dt
    mate_hit = jnp.any(seen.mate_valid & (_gap(step_ends, mate_next, 2 * w.r_self) <= margin), -1)
    downed = seen.opp_valid & ~seen.opp_on
    downed_hit = jnp.any(downed & (_gap(step_ends, seen.opp_pos, w.r_self + w.r_opp) <= margin), -1)
    return (mate_hit | downed_hit).astype(jnp.float32) * 1e9


def scripted_evader(
    config: EnvConfig,
    *,
    horizons: tuple[float, ...] = (1.0, 3.0, 6.0, 10.0),
    pursuer_weight: float = 1.0,
    pursuer_power: float = 2.0,
    worst_case: bool = True,
    wall_weight: float = 0.3,
    obstacle_weight: float = 0.1,
    teammate_weight: float = 0.3,
    safety_margin: float = 0.05,
) -> PolicyFn:
    """Flee pursuers and walls by minimising a repulsive potential along each action's arc.

    For each action allowed by ``action_mask`` the evader follows that action's arc (constant v,
    omega) to the times ``t = control_dt * h`` for ``h`` in ``horizons`` and sums, over those points
    x(t), the potential

        U = Σ_active pursuers w_p / d_j(t)^power  +  w_w / gap_wall  +  Σ_obstacles w_o / gap
          + Σ_teammates w_t / gap  +  Σ_incapacitated pursuers w_t / gap

    where ``d_j(t) = |x(t) - p_j| - v_p t`` is the distance to pursuer j's worst-case reachable disc
    (``worst_case=True``; with False, ``|x(t) - (p_j + u_j t)|``, the pursuer extrapolated by its
    observed velocity u_j). Teammates are extrapolated by their observed velocity; incapacitated
    agents and obstacles stand still. The wall's centre comes from the own features (r_o, theta_o).
    Every distance is floored at 5 mm, so touching costs a lot but stays finite. The evader takes
    the action of least summed potential; looking several steps ahead keeps it out of corners.

    Args:
      config: the game; uses the arena radius, the evader team's action table, both teams' radii,
        the pursuers' v_max and ``control_dt``.
      horizons: look-ahead times along the arc, in control steps.
      pursuer_weight, pursuer_power: pursuer term ``w_p / d^power`` (power 2 favours the nearest).
      worst_case: pursuers as reachable discs (True) or velocity-extrapolated points (False).
      wall_weight, obstacle_weight, teammate_weight: weights of the ``w / gap`` terms, in metres.
      safety_margin: gap in metres; actions whose next-step end point comes this close to a
        teammate or a downed pursuer are taken only when nothing else is valid.

    Returns:
      ``policy(obs, rng) -> int32 [E]`` (``rng`` is unused: the policy is deterministic).
    """
    R, vmax, dt = config.arena.radius, config.evader.max_speed, config.control_dt
    weights = _Weights(
        pursuer=pursuer_weight,
        pursuer_power=pursuer_power,
        wall=wall_weight,
        obstacle=obstacle_weight,
        teammate=teammate_weight,
        r_self=config.evader.radius,
        r_opp=config.pursuer.radius,
    )
    times = np.asarray(horizons, dtype=np.float64) * dt
    ends = jnp.asarray(_end_points(config, "evader", times)[0])  # [n, H, 2]
    t = jnp.asarray(times, dtype=jnp.float32)  # [H]
    reach = config.pursuer.max_speed * t if worst_case else jnp.zeros_like(t)  # [H]
    follow = 0.0 if worst_case else 1.0
    step_ends = jnp.asarray(_end_points(config, "evader", [dt])[0][:, 0])  # [n, 2]

    def one(own, mates, mate_valid, opps, opp_valid, obst, obst_valid, action_mask):
        seen = _seen(mates, mate_valid, opps, opp_valid, R, vmax)
        walls = _walls(own, obst, obst_valid, R)
        # Agents at each look-ahead time: [H, M, 2]; the incapacitated ones stay where they are.
        opp_vel = follow * jnp.where(seen.opp_on[:, None], seen.opp_vel, 0.0)
        opp_at = seen.opp_pos + opp_vel * t[:, None, None]
        mate_vel = jnp.where(seen.mate_on[:, None], seen.mate_vel, 0.0)
        mate_at = seen.mate_pos + mate_vel * t[:, None, None]

        def at_time(x, opp_t, mate_t, reach_t):  # x [n, 2]: every action's arc point at one time
            return _potential(x, opp_t, mate_t, reach_t, seen, walls, weights)

        potential = jax.vmap(at_time, in_axes=(1, 0, 0, 0))(ends, opp_at, mate_at, reach)
        # The potential alone can be swamped by the pursuer terms: never end the next step
        # within `safety_margin` of a teammate or a downed pursuer.
        unsafe = _unsafe(step_ends, seen, dt, weights, safety_margin)
        return _masked_argmin(jnp.sum(potential, axis=0) + unsafe, action_mask)

    fields = ("own", "teammates", "teammate_mask", "opponents", "opponent_mask")
    return _per_agent(one, (*fields, "obstacles", "obstacle_mask"))


# ----------------------------------------------------------------------------- random


def random_policy(config: EnvConfig, team: str) -> PolicyFn:
    """Uniform over each agent's valid actions (categorical over ``where(action_mask, 0, -inf)``).

    Args:
      config: the game (only checked: the mask in the observation carries the action count).
      team: "pursuer" or "evader".

    Returns:
      ``policy(obs, rng) -> int32 [A]``; a fresh ``rng`` per call gives fresh draws.
    """
    config.team(team)  # validates the team name

    def policy(obs: dict[str, jax.Array], rng: jax.Array) -> jax.Array:
        logits = jnp.where(obs["action_mask"], 0.0, -jnp.inf)
        return jax.random.categorical(rng, logits, axis=-1).astype(jnp.int32)

    return policy


# ----------------------------------------------------------------------------- registry


def _scripted(config: EnvConfig, team: str) -> PolicyFn:
    factories = {"pursuer": scripted_pursuer, "evader": scripted_evader}
    config.team(team)  # validates the team name
    return factories[team](config)


POLICIES: dict[str, Callable[[EnvConfig, str], PolicyFn]] = {
    "scripted": _scripted,
    "random": random_policy,
}
"""Name -> factory ``(config, team) -> policy``."""
assert tuple(POLICIES) == BUILTIN_POLICIES


def make_policy(name: str, config: EnvConfig, team: str) -> Policy:
    """A named builtin policy for one team; unknown names or teams raise ValueError.

    Args:
      name: a key of `POLICIES` ("scripted", "random").
      config: the game the policy plays.
      team: "pursuer" or "evader".
    """
    if name not in POLICIES:
        raise ValueError(f"unknown policy {name!r}; known policies: {', '.join(POLICIES)}")
    if team not in TEAMS:
        raise ValueError(f"unknown team {team!r}; expected one of {TEAMS}")
    return builtin_policy(name, team, POLICIES[name](config, team))


__all__ = [
    "POLICIES",
    "make_policy",
    "random_policy",
    "scripted_evader",
    "scripted_pursuer",
]
