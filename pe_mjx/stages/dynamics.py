"""Actions to motion: the action tables (paper eq. (2)) and the two backends' integrators.

* kinematic: eq. (1) integrated exactly (constant v, omega over the step: an arc).
* MJX: the robots of `pe_mjx.scene` stepped by `mujoco.mjx`, `num_substeps` physics steps per
  control step, each commanded the chord velocity of its piece of the arc (`integrate_mjx`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pe_mjx.config import EnvConfig, TeamConfig
from pe_mjx.names import TEAMS
from pe_mjx.stages.geometry import cos_sin, wrap_angle


def action_table(team: TeamConfig) -> tuple[np.ndarray, np.ndarray]:
    """(v [n_actions], omega [n_actions]) of a team, paper eq. (2), 0-based.

    Action index = n_v * N_omega + n_omega.
    """
    speeds = np.linspace(0.0, team.max_speed, team.num_speeds)
    if team.num_turn_rates == 1:
        rates = np.zeros(1)
    else:
        rates = np.linspace(-team.max_turn_rate, team.max_turn_rate, team.num_turn_rates)
    v = np.repeat(speeds, team.num_turn_rates)
    w = np.tile(rates, team.num_speeds)
    return v.astype(np.float32), w.astype(np.float32)


def arc_offsets(v: np.ndarray, w: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Displacement in the heading frame (forward, left) after each time: [n_actions, T, 2]."""
    v, w, t = v[:, None].astype(np.float64), w[:, None].astype(np.float64), times[None, :]
    small = np.abs(w) < 1e-9
    w_safe = np.where(small, 1.0, w)
    fwd = np.where(small, v * t, v * np.sin(w * t) / w_safe)
    left = np.where(small, 0.0, v * (1 - np.cos(w * t)) / w_safe)
    return np.stack([fwd, left], axis=-1).astype(np.float32)


@struct.dataclass
class Commands:
    """The commanded unicycle velocities of N agents for one step (zero for inactive agents)."""

    speed: jax.Array  # [N] forward speed v
    turn: jax.Array  # [N] turn rate omega
    invalid_actions: jax.Array  # float32 []: out-of-range action indices given (then clamped)


def commands(config: EnvConfig, actions: dict[str, jax.Array], active: jax.Array) -> Commands:
    """Action indices {"pursuer": int [P], "evader": int [E]} -> `Commands`.

    An index out of [0, num_actions) is clamped to the nearest valid one (a negative one to 0, a
    too large one to the last) and counted (a plain gather would clamp large indices silently and
    wrap negative ones). `active` bool [N]: inactive agents get v = omega = 0.
    """
    tables = {t: action_table(config.team(t)) for t in TEAMS}
    invalid = sum(
        jnp.sum((a < 0) | (a >= len(tables[t][0])))
        for t, a in ((t, jnp.asarray(actions[t])) for t in TEAMS)
    ).astype(jnp.float32)
    index = {t: jnp.clip(jnp.asarray(actions[t]), 0, len(tables[t][0]) - 1) for t in TEAMS}
    v_p, w_p = (jnp.asarray(t)[index["pursuer"]] for t in tables["pursuer"])
    v_e, w_e = (jnp.asarray(t)[index["evader"]] for t in tables["evader"])
    speed = jnp.where(active, jnp.concatenate([v_p, v_e]), 0.0)
    turn = jnp.where(active, jnp.concatenate([w_p, w_e]), 0.0)
    return Commands(speed=speed, turn=turn, invalid_actions=invalid)


@struct.dataclass
class Motion:
    """Where N agents end a control step."""

    pos: jax.Array  # [N, 2]
    yaw: jax.Array  # [N], wrapped into [-pi, pi)
    vel: jax.Array  # [N, 2] the unicycle's world velocity at the end of the step


def integrate_kinematic(
    config: EnvConfig, pos: jax.Array, yaw: jax.Array, speed: jax.Array, turn: jax.Array
) -> Motion:
    """The exact arc of constant (v, omega) [N] over `control_dt` from poses [N, 2], [N]."""
    dt = config.control_dt
    small = jnp.abs(turn) < 1e-9
    safe = jnp.where(small, 1.0, turn)
    new_yaw = yaw + turn * dt
    c0, s0 = cos_sin(yaw)
    c1, s1 = cos_sin(new_yaw)
    dx = jnp.where(small, speed * dt * c0, speed * (s1 - s0) / safe)
    dy = jnp.where(small, speed * dt * s0, speed * (c0 - c1) / safe)
    vel = speed[:, None] * jnp.stack([c1, s1], axis=-1)
    return Motion(pos=pos + jnp.stack([dx, dy], axis=-1), yaw=wrap_angle(new_yaw), vel=vel)


def integrate_mjx(
    config: EnvConfig, mjx_model: Any, data: Any, speed: jax.Array, turn: jax.Array
) -> tuple[Motion, Any]:
    """`num_substeps` MJX physics steps from `data` (mjx.Data) under (v, omega) [N].

    The velocity actuators are deadbeat, and before each physics step they get the chord velocity
    of that step's piece of the commanded arc, ``v sinc(omega dt / 2) (cos psi_m, sin psi_m)`` and
    ``omega``, psi_m the heading at the middle of the physics step: every physics step ends on the
    arc the action mask predicted (docs/design.md, "MJX actuation"). Returns the motion and the
    new mjx.Data.
    """
    from mujoco import mjx

    half = 0.5 * config.physics_dt * turn
    # A chord of an arc of angle 2h and radius v / omega is v dt sin(h) / h long and points
    # along the heading at its middle; sin(h) / h to float32 precision (|h| <= 0.16 rad).
    h2 = half * half
    chord_speed = speed * (1 - h2 / 6 * (1 - h2 / 20 * (1 - h2 / 42)))

    def substep(d, _):
        c, s = cos_sin(d.qpos[2::3] + half)
        ctrl = jnp.stack([chord_speed * c, chord_speed * s, turn], axis=1)
        return mjx.step(mjx_model, d.replace(ctrl=ctrl.reshape(-1))), None

    if config.num_substeps == 1:
        data, _ = substep(data, None)
    else:
        data, _ = jax.lax.scan(substep, data, None, length=config.num_substeps)
    q = data.qpos.reshape(-1, 3)
    yaw = wrap_angle(q[:, 2])
    # The unicycle's velocity at the end of the step (the kinematic backend's), not the last
    # chord's: observations are the same in both backends.
    c1, s1 = cos_sin(yaw)
    vel = speed[:, None] * jnp.stack([c1, s1], axis=-1)
    return Motion(pos=q[:, :2], yaw=yaw, vel=vel), data


__all__ = [
    "Commands",
    "Motion",
    "action_table",
    "arc_offsets",
    "commands",
    "integrate_kinematic",
    "integrate_mjx",
]
