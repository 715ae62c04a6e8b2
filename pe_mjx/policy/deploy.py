"""Policies on real robots: measured poses in, the env's own observations, (v, omega) out.

A `Controller` takes what a real setup has: each robot's pose (x, y, yaw) with a timestamp, at
whatever rate the localisation delivers it (per robot or per team), the obstacle circles, and
which robots are down. At any moment `act` builds the observations of SPEC 2.5, with the action
mask of SPEC 2.4 (the minimum turning radius included), through `PursuitEvasionEnv.observe`, the
function `step` itself uses, so nothing is re-implemented here; it runs one policy per team and
returns each robot's command (v, omega) from the team's action table.

Velocities (the env observes each agent's world velocity at the end of its last step, `v (cos
psi, sin psi)` for a unicycle) are estimated from each robot's pose history by an arc fit:

* reference pose: among the robot's older poses, the one whose age relative to its newest pose
  is closest to `velocity_window` (default: the control step). Timestamps can be irregular and
  differ between robots; only their differences are used.
* with dt, the time between the two poses, d_psi = wrap(psi_1 - psi_0) and the chord
  c = p_1 - p_0, a constant (v, omega) arc gives omega = d_psi / dt and a chord of length
  v dt sinc(d_psi / 2) along the heading at the middle, psi_m = psi_0 + d_psi / 2. So
  v = (c . (cos psi_m, sin psi_m)) / (dt sinc(d_psi / 2)): exact for unicycle arcs, whatever dt,
  negative when the robot backs up, and sideways motion (a Mecanum base, pose noise across the
  heading) does not count.
* velocity = v (cos psi_1, sin psi_1), along the newest heading, as in the env; zero for a robot
  with a single pose (as at reset) and for a robot that is down (as the env has it).

The estimate is exact when the commands were constant over the window (tests/policy/test_deploy.py:
a simulated episode fed at the control rate gives the env's observations within 1e-4). A longer
window averages pose noise (the error is about sqrt(2) sigma / window) at the cost of lag: after
a command change, the estimate mixes the two arcs until the window has passed.

The policies see the newest pose of each robot; poses are not extrapolated to a common time, so
feed poses at least as often as `act` is called.

Poses the env could not be in are refused (`ValueError` naming the robot) before any policy
runs, by the env's own geometry (`pe_mjx.stages.events`): a robot that is up must lie inside the
arena clear of the wall (|p| + r < R), of every obstacle and of every other robot (a robot that is
down counts as an obstacle); a robot that is down may lie at the wall or against what downed it,
but not more than one control step at its top speed outside the arena. Such a pose means a
localisation fault, a wrong frame (the arena centred on the origin, metres), or a robot that is
down and should be marked so in `down`.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.config import EnvConfig
from pe_mjx.env import PursuitEvasionEnv, World
from pe_mjx.names import ACTIVE, OBSTACLE, TEAMS
from pe_mjx.policy.core import PolicyFn
from pe_mjx.stages.dynamics import action_table


def _wrap(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def arc_speed(times: np.ndarray, poses: np.ndarray) -> float:
    """Signed speed v of the constant (v, omega) arc from pose 0 to pose 1 (module docstring).

    Args:
      times: [2] seconds, times[1] > times[0].
      poses: [2, 3] x, y, yaw.
    """
    dt = float(times[1] - times[0])
    d_yaw = float(_wrap(poses[1, 2] - poses[0, 2]))
    mid = poses[0, 2] + 0.5 * d_yaw
    along = (poses[1, 0] - poses[0, 0]) * np.cos(mid) + (poses[1, 1] - poses[0, 1]) * np.sin(mid)
    return float(along / (dt * np.sinc(0.5 * d_yaw / np.pi)))  # np.sinc(x) = sin(pi x) / (pi x)


def _jitted(policy: PolicyFn) -> Callable[[Any, jax.Array], jax.Array]:
    """`policy` compiled. `jax.jit` keys its cache on the callable, and a `pe_mjx.Policy` (a
    frozen dataclass holding its variables in dicts) cannot be hashed: compile a closure."""

    def call(obs: Any, rng: jax.Array) -> jax.Array:
        return policy(obs, rng)

    return jax.jit(call)


@dataclasses.dataclass
class _Track:
    """One robot's recent poses, oldest first."""

    times: collections.deque
    poses: collections.deque


class Controller:
    """Builds the env's observations from measured poses and runs one policy per team.

    Args:
      config: the game (team sizes, speeds, action tables, arena radius, minimum turning radius,
        control step); `pe_mjx.get_preset("4-2-2")` is the paper's robot setup. The obstacle count
        comes from the obstacles given to `observe`/`act`, not from the config.
      policies: team -> policy; a team without one can still be observed, not commanded.
      velocity_window: seconds between the two poses of the velocity fit (default: the control
        step, which makes the estimate exact for the env's piecewise-constant commands).
      history: poses kept per robot (enough to span the window at the pose rate).
      seed: seeds the rng handed to the policies (greedy policies ignore it).
    """

    def __init__(
        self,
        config: EnvConfig,
        policies: Mapping[str, PolicyFn] | None = None,
        *,
        velocity_window: float | None = None,
        history: int = 64,
        seed: int = 0,
    ):
        if not isinstance(config, EnvConfig):
            raise TypeError(
                f"config must be an EnvConfig (e.g. pe_mjx.get_preset('4-2-2')), got "
                f"{type(config).__name__}"
            )
        self.config = config
        self.policies = dict(policies or {})
        unknown = set(self.policies) - set(TEAMS)
        if unknown:
            raise ValueError(f"unknown teams {sorted(unknown)}; expected some of {TEAMS}")
        self.velocity_window = config.control_dt if velocity_window is None else velocity_window
        if not self.velocity_window > 0:
            raise ValueError(f"velocity_window must be > 0, got {self.velocity_window}")
        if history < 2:
            raise ValueError(f"history must be >= 2 poses, got {history}")
        self.counts = {t: config.team(t).num_agents for t in TEAMS}
        self._tracks = {
            t: [
                _Track(collections.deque(maxlen=history), collections.deque(maxlen=history))
                for _ in range(n)
            ]
            for t, n in self.counts.items()
        }
        self.actions = {t: action_table(config.team(t)) for t in TEAMS}
        self._observe: dict[int, Callable[[World], Any]] = {}  # by obstacle count
        self._policies = {t: _jitted(p) for t, p in self.policies.items()}
        self._rng = jax.random.key(seed)

    # ------------------------------------------------------------------ poses in

    def update(self, team: str, index: int, pose: Any, time: float) -> None:
        """Records robot `index` of `team` at `pose` (x, y, yaw in the arena frame, metres and
        radians, the arena centred on the origin) measured at `time` seconds. A pose that is not
        newer than the robot's newest one is ignored (out-of-order delivery)."""
        track = self._track(team, index)
        # Each wrong shape or type is a ValueError naming the robot, not numpy's own words.
        try:
            pose = np.asarray(pose, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"{team} {index}: pose must be numbers (x, y, yaw), got {pose!r}"
            ) from None
        try:
            time = float(time)
        except (TypeError, ValueError):
            raise ValueError(f"{team} {index}: time must be seconds, got {time!r}") from None
        if pose.shape != (3,):
            raise ValueError(f"{team} {index}: pose must be (x, y, yaw), got shape {pose.shape}")
        if not np.all(np.isfinite(pose)) or not np.isfinite(time):
            raise ValueError(f"{team} {index}: pose and time must be finite, got {pose}, {time}")
        if track.times and time <= track.times[-1]:
            return
        track.times.append(float(time))
        track.poses.append(pose)

    def update_team(self, team: str, poses: Any, times: Any) -> None:
        """`update` for a whole team: poses [A, 3], times a scalar or [A]."""
        self._track(team, 0)  # the team is known
        n = self.counts[team]
        try:
            poses = np.asarray(poses, dtype=np.float64)
            times = np.asarray(times, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{team}: poses and times must be numbers") from None
        if poses.shape != (n, 3):
            raise ValueError(f"{team}: poses must be [{n}, 3] (x, y, yaw), got {list(poses.shape)}")
        if times.shape not in ((), (n,)):
            raise ValueError(f"{team}: times must be one time or {n}, got {list(times.shape)}")
        times = np.broadcast_to(times, (n,))
        for i in range(n):
            self.update(team, i, poses[i], float(times[i]))

    def _track(self, team: str, index: int) -> _Track:
        if team not in TEAMS:
            raise ValueError(f"unknown team {team!r}; expected one of {TEAMS}")
        if not isinstance(index, int | np.integer) or isinstance(index, bool):
            raise ValueError(f"{team} index must be an integer, got {index!r}")
        if not 0 <= index < self.counts[team]:
            raise ValueError(f"{team} index {index} out of range 0..{self.counts[team] - 1}")
        return self._tracks[team][index]

    # ------------------------------------------------------------------ estimates

    def poses(self) -> dict[str, np.ndarray]:
        """Each robot's newest pose: team -> [A, 3]; ValueError if a robot has none yet."""
        out = {}
        for team, tracks in self._tracks.items():
            missing = [i for i, tr in enumerate(tracks) if not tr.poses]
            if missing:
                raise ValueError(f"no pose received yet for {team}s {missing}")
            out[team] = np.stack([tr.poses[-1] for tr in tracks])
        return out

    def velocities(self) -> dict[str, np.ndarray]:
        """Each robot's estimated world velocity (module docstring): team -> [A, 2]."""
        out = {}
        for team, tracks in self._tracks.items():
            vel = np.zeros((len(tracks), 2))
            for i, tr in enumerate(tracks):
                if len(tr.times) < 2:
                    continue
                times = np.asarray(tr.times)
                ages = times[-1] - times[:-1]
                j = int(np.argmin(np.abs(ages - self.velocity_window)))
                pair = np.stack([tr.poses[j], tr.poses[-1]])
                v = arc_speed(times[[j, -1]], pair)
                vel[i] = v * np.array([np.cos(pair[1, 2]), np.sin(pair[1, 2])])
            out[team] = vel
        return out

    def world(self, obstacles: Any, down: Mapping[str, Any] | None = None) -> World:
        """The env's `World` of the newest poses and estimated velocities.

        Args:
          obstacles: [K, 3] circles x, y, radius (K may be 0).
          down: team -> bool [A], robots that are out (collided or captured); they keep being
            observed as static circles with flag g = 1, with zero velocity.
        """
        poses, vel = self.poses(), self.velocities()
        active = np.concatenate([self._active(down, t) for t in TEAMS])
        obstacles = self._obstacles(obstacles)
        self._check_geometry(poses, active, obstacles)
        pose = np.concatenate([poses[t] for t in TEAMS]).astype(np.float32)
        vel = np.concatenate([vel[t] for t in TEAMS]) * active[:, None]
        n = len(active)
        return World(
            pos=jnp.asarray(pose[:, :2]),
            yaw=jnp.asarray(_wrap(pose[:, 2]), jnp.float32),
            vel=jnp.asarray(vel, jnp.float32),
            active=jnp.asarray(active),
            # The cause is not observed; any nonzero one marks the robot down.
            cause=jnp.asarray(np.where(active, ACTIVE, OBSTACLE), jnp.int32),
            distance=jnp.zeros(n),
            captures=jnp.zeros(n, jnp.int32),
            obstacles=jnp.asarray(obstacles),
            step=jnp.zeros((), jnp.int32),
        )

    def _active(self, down: Mapping[str, Any] | None, team: str) -> np.ndarray:
        n = self.counts[team]
        if down is not None and set(down) - set(TEAMS):
            raise ValueError(f"down: unknown teams {sorted(set(down) - set(TEAMS))}")
        if down is None or team not in down:
            return np.ones(n, bool)
        d = np.asarray(down[team], dtype=bool).reshape(-1)
        if d.shape != (n,):
            raise ValueError(f"down[{team!r}] must have {n} flags, got {d.shape[0]}")
        return ~d

    def _check_geometry(
        self, poses: dict[str, np.ndarray], active: np.ndarray, obstacles: np.ndarray
    ) -> None:
        """Refuses poses the env could not be in (module docstring): `ValueError` naming the
        first robot outside the arena or overlapping the wall, an obstacle or another robot."""
        names = [f"{t} {i}" for t in TEAMS for i in range(self.counts[t])]
        pos = np.concatenate([poses[t][:, :2] for t in TEAMS])
        radius = np.concatenate(
            [np.full(self.counts[t], self.config.team(t).radius) for t in TEAMS]
        )
        reach = (
            np.concatenate([np.full(self.counts[t], self.config.team(t).max_speed) for t in TEAMS])
            * self.config.control_dt
        )
        arena = self.config.arena.radius
        norm = np.hypot(pos[:, 0], pos[:, 1])

        def at(i: int) -> str:
            return f"{names[i]} at ({pos[i, 0]:.3g}, {pos[i, 1]:.3g})"

        for i in range(len(names)):
            if not active[i] and norm[i] - radius[i] - reach[i] >= arena:
                raise ValueError(
                    f"{at(i)} is outside the arena (radius {arena:g} m, centred on the origin); "
                    f"poses are metres in the arena frame"
                )
            if active[i] and norm[i] + radius[i] >= arena:
                where = "is outside the arena" if norm[i] >= arena else "touches the arena wall"
                raise ValueError(
                    f"{at(i)} {where} (radius {arena:g} m, centred on the origin): the env "
                    f"would have it down; fix its pose or mark it in `down`"
                )
        if len(obstacles):
            gap = np.hypot(*(pos[:, None, :] - obstacles[None, :, :2]).transpose(2, 0, 1))
            gap = gap - radius[:, None] - obstacles[None, :, 2]
            for i, k in np.argwhere((gap <= 0) & active[:, None])[:1]:
                raise ValueError(
                    f"{at(i)} overlaps obstacle {k} at ({obstacles[k, 0]:.3g}, "
                    f"{obstacles[k, 1]:.3g}) radius {obstacles[k, 2]:.3g}: the env would have "
                    f"it down; fix its pose or mark it in `down`"
                )
        gap = np.hypot(*(pos[:, None, :] - pos[None, :, :]).transpose(2, 0, 1))
        gap = gap - radius[:, None] - radius[None, :]
        touching = (gap <= 0) & ~np.eye(len(names), dtype=bool) & (active[:, None] | active)
        for i, j in np.argwhere(np.triu(touching))[:1]:
            raise ValueError(
                f"{at(i)} overlaps {at(j)} (bodies of radius {radius[i]:g} and {radius[j]:g} m): "
                f"the env would have them down; fix their poses or mark them in `down`"
            )

    @staticmethod
    def _obstacles(obstacles: Any) -> np.ndarray:
        obs = np.asarray(obstacles, dtype=np.float32).reshape(-1, 3) if np.size(obstacles) else None
        if obs is None:
            return np.zeros((0, 3), np.float32)
        if not np.all(np.isfinite(obs)) or np.any(obs[:, 2] <= 0):
            raise ValueError("obstacles must be finite (x, y, r) rows with r > 0")
        return obs

    # ------------------------------------------------------------------ observations and actions

    def observe(
        self, obstacles: Any, down: Mapping[str, Any] | None = None
    ) -> dict[str, dict[str, jax.Array]]:
        """The env's observations (SPEC 2.5, action masks of 2.4) for the current poses:
        team -> observation dict with an agent axis, exactly as `state.obs`."""
        world = self.world(obstacles, down)
        k = int(world.obstacles.shape[0])
        if k not in self._observe:
            arena = dataclasses.replace(self.config.arena, num_obstacles=k)
            env = PursuitEvasionEnv(self.config.replace(arena=arena), backend="kinematic")
            self._observe[k] = jax.jit(env.observe)
        return self._observe[k](world)

    def act(self, obstacles: Any, down: Mapping[str, Any] | None = None) -> dict[str, np.ndarray]:
        """Commands for every robot of each team that has a policy: team -> [A, 2] (v in m/s,
        omega in rad/s); (0, 0) for robots that are down."""
        obs = self.observe(obstacles, down)
        out = {}
        for team, policy in self._policies.items():
            self._rng, rng = jax.random.split(self._rng)
            actions = np.asarray(policy(obs[team], rng))
            n_actions = len(self.actions[team][0])
            if (
                actions.shape != (self.counts[team],)
                or not np.issubdtype(actions.dtype, np.integer)
                or np.any((actions < 0) | (actions >= n_actions))
            ):
                raise ValueError(
                    f"the {team} policy returned {actions.dtype}{list(actions.shape)} "
                    f"{actions.tolist()}; expected {self.counts[team]} integer actions in "
                    f"[0, {n_actions})"
                )
            v, omega = (table[actions] for table in self.actions[team])
            active = self._active(down, team)
            out[team] = np.where(active[:, None], np.stack([v, omega], axis=-1), 0.0)
        return out
