"""Action masks (SPEC 2.4): the actions whose look-ahead arc stays clear of wall and obstacles.

The mask keeps `MASK_MARGIN` (0.1 mm) from the wall and obstacles, so float32 rounding never lets
an unmasked action end a step touching them.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.config import EnvConfig, TeamConfig
from pe_mjx.stages.dynamics import action_table, arc_offsets

# The action mask keeps this much (metres) from the wall and obstacles, so that float32 rounding
# (the mask works in the heading frame on squared distances, the events in the world frame) never
# lets an unmasked action end a step touching; without it, about 1 in 10^5 random near-wall
# actions did.
MASK_MARGIN = 1e-4


def turning_mask(team: TeamConfig) -> np.ndarray:
    """Minimum turning radius (paper V): mask v / |omega| < R_min; v = 0 keeps omega ~ 0."""
    v, w = action_table(team)
    ok = np.ones(team.num_actions, dtype=bool)
    if team.min_turning_radius > 0:
        moving = v > 0
        with np.errstate(divide="ignore", invalid="ignore"):  # 0 / 0 at v = omega = 0
            radius = np.where(np.abs(w) > 0, v / np.abs(w), np.inf)
        ok = np.where(moving, radius >= team.min_turning_radius, np.abs(w) == np.abs(w).min())
    return ok


def stop_actions(team: TeamConfig) -> np.ndarray:
    """bool [n_actions]: the v = 0 actions the turning mask allows."""
    v, _ = action_table(team)
    return (v == 0) & turning_mask(team)


@dataclasses.dataclass(frozen=True, eq=False)
class MaskTable:
    """A team's constants for `action_mask`, built once (numpy; static under `jit`).

    The mask checks each distinct arc point once: the leading `num_stop` actions (v = 0) all stay
    at the agent's position; the other actions' `num_points` points each are flattened to [M]
    (`x`, `y`, `sq` = x^2 + y^2, in the heading frame).
    """

    radius: float
    num_stop: int
    num_points: int
    x: np.ndarray  # [M]
    y: np.ndarray  # [M]
    sq: np.ndarray  # [M]
    allowed: np.ndarray  # bool [n_actions]: `turning_mask`
    stop: np.ndarray  # bool [n_actions]: `stop_actions`


def mask_table(config: EnvConfig, team: str) -> MaskTable:
    """The `MaskTable` of `team` ("pursuer" or "evader") under `config`."""
    tc = config.team(team)
    v, w = action_table(tc)
    times = config.mask_horizon * np.arange(1, config.mask_points + 1) / config.mask_points
    offsets = arc_offsets(v, w, times)
    n_stop = tc.num_turn_rates
    assert np.all(v[:n_stop] == 0) and np.all(v[n_stop:] > 0)
    moving = offsets[n_stop:].reshape(-1, 2)
    return MaskTable(
        radius=tc.radius,
        num_stop=n_stop,
        num_points=offsets.shape[1],
        x=moving[:, 0],
        y=moving[:, 1],
        sq=np.sum(moving**2, axis=1),
        allowed=turning_mask(tc),
        stop=stop_actions(tc),
    )


def action_mask(
    config: EnvConfig,
    table: MaskTable,
    origin_hx: jax.Array,
    origin_hy: jax.Array,
    obs_hx: jax.Array,
    obs_hy: jax.Array,
    obstacles: jax.Array,
) -> jax.Array:
    """bool [A, n_actions]: False where the look-ahead arc hits the wall or an obstacle.

    Works in each agent's heading frame, where the arc points are constants, and compares squared
    distances (no sqrt). `origin_hx`, `origin_hy` [A] and `obs_hx`, `obs_hy` [A, K] are the
    offsets to the world origin and to the obstacle centres in the heading frame of the team's A
    agents (their rows of `Geometry`); `obstacles` [K, 3].
    """
    a = origin_hx.shape[0]
    r = table.radius
    ox, oy, oo = jnp.asarray(table.x), jnp.asarray(table.y), jnp.asarray(table.sq)
    # The agent's position relative to the arena centre is -origin_h; the wall is hit where
    # |p + o| + r >= R, i.e. |p + o|^2 >= (R - r)^2.
    px, py = -origin_hx, -origin_hy
    wall = (config.arena.radius - r - MASK_MARGIN) ** 2
    bad_move = (px[:, None] + ox) ** 2 + (py[:, None] + oy) ** 2 >= wall  # [A, M]
    bad_stop = px**2 + py**2 >= wall  # [A]: the v = 0 actions stay at p
    num_obstacles = config.arena.num_obstacles
    if num_obstacles:
        # Obstacle k is hit where |o - h_k| <= r + r_k, h_k the offset to its centre, i.e.
        # |o|^2 - 2 o.h_k <= room_k = (r + r_k)^2 - |h_k|^2.
        room = (r + obstacles[:, 2] + MASK_MARGIN) ** 2 - (obs_hx**2 + obs_hy**2)  # [A, K]
        ax, ay = -2 * obs_hx.T[:, :, None], -2 * obs_hy.T[:, :, None]  # [K, A, 1]
        room_k = room.T[:, :, None]
        # [K, A, M], K outer for a fast reduction, in chunks of 32 obstacles: XLA splits longer
        # reductions and then materialises the whole [K, A, M] (1.6x slower at 120 obstacles).
        for k in range(0, num_obstacles, 32):
            ks = slice(k, k + 32)
            bad_move = bad_move | jnp.any(oo + ax[ks] * ox + ay[ks] * oy <= room_k[ks], axis=0)
        bad_stop = bad_stop | jnp.any(room >= 0, axis=1)
    bad = jnp.concatenate(
        [
            jnp.broadcast_to(bad_stop[:, None], (a, table.num_stop)),
            jnp.any(bad_move.reshape(a, -1, table.num_points), axis=2),
        ],
        axis=1,
    )
    mask = ~bad & jnp.asarray(table.allowed)[None, :]
    # Already touching (all masked): leave the stop actions, so something stays valid.
    stop = jnp.asarray(table.stop)[None, :]
    return jnp.where(jnp.any(mask, axis=1, keepdims=True), mask, stop)


__all__ = ["MASK_MARGIN", "MaskTable", "action_mask", "mask_table", "stop_actions", "turning_mask"]
