"""The pursuit-evasion env: a thin class composing the stages of `pe_mjx.stages`, two backends.

Layout: struct-of-arrays over all N = P + E agents, pursuers first. A step reads top to bottom:
commands (`dynamics.commands`), motion (`dynamics.integrate_kinematic` or `integrate_mjx`), the
shared `geometry.Geometry` of the new poses, `events.Events`, reward terms (`rewards`), then
observations with action masks (`observations`, `masks`) and `metrics`. `reset` draws an arena
with `placement.place`. The constants a step needs (per-team mask tables, the MJX model) are
built once in the constructor. `jit` and `vmap` are applied by the caller.

Backends (SPEC 2.2):
  * ``"mjx"`` (default): the robots of `pe_mjx.scene` stepped by `mujoco.mjx`, `num_substeps`
    physics steps per control step. The velocity actuators are deadbeat (gain = inertia /
    physics_dt under the semi-implicit Euler integrator: the joint velocity equals the command
    after one physics step), and before each physics step they get the chord velocity of that
    step's piece of the commanded arc, ``v sinc(omega dt / 2) (cos psi_m, sin psi_m)`` and
    ``omega``, with psi_m the heading at the middle of the physics step. So every physics step
    ends exactly on the arc that the action mask predicted (docs/design.md, "MJX actuation").
  * ``"kinematic"``: eq. (1) integrated exactly (constant v, omega over the step: an arc).

MJX against the kinematic reference (tests/test_rules.py): for the same actions, every event is
the same (agent, step, cause) and poses agree within `MJX_POSE_TOL` (float32 rounding only).

The action mask keeps `MASK_MARGIN` (0.1 mm) from the wall and obstacles, so float32 rounding never
lets an unmasked action end a step touching them.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from pe_mjx import scene
from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.names import ABSENT, ACTIVE, BACKENDS, TEAMS
from pe_mjx.stages import dynamics, events, geometry, masks, metrics, observations, placement
from pe_mjx.stages import rewards as reward_stage
from pe_mjx.stages.geometry import wrap_angle
from pe_mjx.stages.world import World

# MJX poses agree with the kinematic backend's within this (metres and radians) for the same
# actions: both end every control step on the same arc, up to float32 rounding (measured in
# tests/test_rules.py: 1.7e-5 m and 7e-6 rad after 420 steps).
MJX_POSE_TOL = 1e-4


@struct.dataclass
class State:
    """One env state; everything `jit`/`vmap` sees (MuJoCo Playground layout)."""

    world: World
    physics: Any  # mjx.Data for the mjx backend, None for the kinematic one
    obs: dict[str, dict[str, jax.Array]]
    reward: dict[str, jax.Array]  # team -> [A]
    done: jax.Array  # float32 []
    metrics: dict[str, jax.Array]
    info: dict[str, Any]


class PursuitEvasionEnv:
    """Multi-pursuer multi-evader pursuit-evasion under collision avoidance (SPEC 2)."""

    def __init__(self, config: EnvConfig, backend: str = "mjx"):
        if backend not in BACKENDS:
            raise ValueError(f"unknown backend {backend!r}; expected one of {BACKENDS}")
        self.config = config
        self.backend = backend
        p, e = config.pursuer.num_agents, config.evader.num_agents
        self.num_pursuers, self.num_evaders = p, e
        self.num_agents = p + e
        self.num_obstacles = config.arena.num_obstacles
        self.team_slices = observations.team_slices(config)
        self.mask_tables = {t: masks.mask_table(config, t) for t in TEAMS}
        if backend == "mjx":
            from mujoco import mjx

            self.mj_model = scene.build_model(config, layout=None, visual=False)
            self.mjx_model = mjx.put_model(self.mj_model)
            self.mjx_data0 = mjx.make_data(self.mjx_model)
        else:
            self.mj_model = None
            self.mjx_model = None
            self.mjx_data0 = None

    # ----------------------------------------------------------------- public surface

    def num_actions(self, team: str) -> int:
        return self.config.team(team).num_actions

    def poses(self, state: State) -> dict[str, jax.Array]:
        """{"pursuer": [P, 3], "evader": [E, 3]}: x, y, yaw."""
        w = state.world
        pose = jnp.concatenate([w.pos, w.yaw[..., None]], axis=-1)
        return {t: pose[..., s, :] for t, s in self.team_slices.items()}

    def obstacles(self, state: State) -> jax.Array:
        """[K, 3]: x, y, radius."""
        return state.world.obstacles

    def active(self, state: State) -> dict[str, jax.Array]:
        """{"pursuer": bool [P], "evader": bool [E]}."""
        return {t: state.world.active[..., s] for t, s in self.team_slices.items()}

    def split(self, x: jax.Array) -> dict[str, jax.Array]:
        """Splits an [..., N, ...] per-agent array on axis -1 into teams."""
        return {t: x[..., s] for t, s in self.team_slices.items()}

    def observe(self, world: World) -> dict[str, dict[str, jax.Array]]:
        """The observations and action masks `step` would give for `world` (SPEC 2.5, 2.4).

        Pure and jittable; only the poses, velocities, active flags and obstacles are read. For
        controllers that build a `World` from measured poses (`pe_mjx.policy.deploy`).
        """
        geom = geometry.geometry(world.pos, world.yaw, world.obstacles)
        return observations.observe(self.config, self.mask_tables, world, geom)

    # ----------------------------------------------------------------- reset

    def reset(self, rng: jax.Array) -> State:
        """Draws a fresh arena from `rng` (obstacles, poses) and returns its first state."""
        rng, place_rng = jax.random.split(rng)
        placed = placement.place(self.config, place_rng)
        n = self.num_agents
        world = World(
            pos=placed.pos,
            yaw=placed.yaw,
            vel=jnp.zeros((n, 2)),
            active=placed.present,
            cause=jnp.where(placed.present, ACTIVE, ABSENT).astype(jnp.int32),
            distance=jnp.zeros(n),
            captures=jnp.zeros(n, dtype=jnp.int32),
            obstacles=placed.obstacles,
            step=jnp.zeros((), dtype=jnp.int32),
        )
        physics = None
        if self.backend == "mjx":
            qpos = jnp.concatenate([placed.pos, placed.yaw[:, None]], axis=1).reshape(-1)
            physics = self.mjx_data0.replace(qpos=qpos, qvel=jnp.zeros_like(qpos))
        zeros = {t: jnp.zeros(self.config.team(t).num_agents) for t in TEAMS}
        valid = self.split(placed.present)
        step_metrics = metrics.step_metrics(
            self.config,
            world,
            reward_stage.zero_terms(self.config),
            valid,
            jnp.zeros((), jnp.float32),
        )
        info = {
            "rng": rng,
            "truncation": jnp.zeros(()),
            "terminated": jnp.zeros((), dtype=bool),
            "valid": valid,
            "active": valid,
            "placement_ok": placed.ok,
        }
        return State(
            world=world,
            physics=physics,
            obs=self.observe(world),
            reward=zeros,
            done=jnp.zeros(()),
            metrics=step_metrics,
            info=info,
        )

    def reset_to(
        self,
        pursuer: jax.Array,
        evader: jax.Array,
        obstacles: jax.Array,
        rng: jax.Array | None = None,
    ) -> State:
        """A first state with hand-placed poses ([P, 3], [E, 3]: x, y, yaw) and obstacles [K, 3].

        For tests, replays and scripted scenarios; no overlap check is made.
        """
        state = self.reset(jax.random.key(0) if rng is None else rng)
        pursuer, evader = jnp.asarray(pursuer, jnp.float32), jnp.asarray(evader, jnp.float32)
        obstacles = jnp.asarray(obstacles, jnp.float32).reshape(self.num_obstacles, 3)
        poses = jnp.concatenate([pursuer, evader], axis=0)
        if poses.shape != (self.num_agents, 3):
            raise ValueError(
                f"reset_to: expected pursuer [{self.num_pursuers}, 3] and evader "
                f"[{self.num_evaders}, 3] poses, got {pursuer.shape} and {evader.shape}"
            )
        world = state.world.replace(
            pos=poses[:, :2], yaw=wrap_angle(poses[:, 2]), obstacles=obstacles
        )
        physics = state.physics
        if physics is not None:
            physics = physics.replace(qpos=poses.reshape(-1))
        return state.replace(world=world, physics=physics, obs=self.observe(world))

    # ----------------------------------------------------------------- step

    def step(self, state: State, actions: dict[str, jax.Array]) -> State:
        """One control step: move, then events (wall, obstacle, capture, agent), then rewards.

        Args:
          state: the current state.
          actions: {"pursuer": int32 [P], "evader": int32 [E]} action indices. An index out of
            [0, num_actions) is clamped to the nearest valid one (a negative one to 0, a too
            large one to the last) and counted in `metrics["invalid_actions"]` (a plain gather
            would clamp large indices silently and wrap negative ones).
        """
        cfg = self.config
        w = state.world
        was_active = w.active
        cmd = dynamics.commands(cfg, actions, was_active)
        if self.backend == "mjx":
            motion, physics = dynamics.integrate_mjx(
                cfg, self.mjx_model, state.physics, cmd.speed, cmd.turn
            )
        else:
            motion = dynamics.integrate_kinematic(cfg, w.pos, w.yaw, cmd.speed, cmd.turn)
            physics = None
        # Incapacitated agents never move again (their commands are zero; this makes it exact).
        pos = jnp.where(was_active[:, None], motion.pos, w.pos)
        yaw = jnp.where(was_active, motion.yaw, w.yaw)

        # Offsets and distances are computed once and shared by events, rewards and observations.
        geom = geometry.geometry(pos, yaw, w.obstacles)
        ev = events.events(cfg, geom, was_active, w.obstacles)
        # The first cause sticks (an absent agent keeps ABSENT: it is never active).
        active, cause = ev.active, jnp.where(w.cause != ACTIVE, w.cause, ev.cause)
        vel = jnp.where(active[:, None], motion.vel, 0.0)
        if physics is not None:
            # qpos is the world pose with the yaw wrapped, as in the kinematic backend (an
            # unwrapped yaw would lose float32 precision as it grows over an episode).
            qpos = jnp.concatenate([pos, yaw[:, None]], axis=1).reshape(-1)
            qvel = jnp.where(active[:, None], physics.qvel.reshape(-1, 3), 0.0).reshape(-1)
            physics = physics.replace(qpos=qpos, qvel=qvel)

        step_count = w.step + 1
        world = World(
            pos=pos,
            yaw=yaw,
            vel=vel,
            active=active,
            cause=cause,
            distance=w.distance + jnp.linalg.norm(pos - w.pos, axis=-1),
            captures=w.captures + ev.new_captures,
            obstacles=w.obstacles,
            step=step_count,
        )
        terms = reward_stage.reward_terms(
            cfg, geom, w.pos, pos, was_active, active, ev.capture_pairs, w.obstacles
        )
        valid = self.split(was_active)
        p_alive = jnp.any(active[: self.num_pursuers])
        e_alive = jnp.any(active[self.num_pursuers :])
        terminated = ~(p_alive & e_alive)
        truncated = (step_count >= cfg.max_steps) & ~terminated
        done = (terminated | truncated).astype(jnp.float32)
        info = dict(state.info)
        info.update(
            truncation=truncated.astype(jnp.float32),
            terminated=terminated,
            valid=valid,
            active=self.split(active),
        )
        return State(
            world=world,
            physics=physics,
            obs=observations.observe(cfg, self.mask_tables, world, geom),
            reward=reward_stage.team_rewards(terms, valid),
            done=done,
            metrics=metrics.step_metrics(cfg, world, terms, valid, cmd.invalid_actions),
            info=info,
        )


class AutoResetWrapper:
    """Resets finished arenas with a *fresh* draw from the state's rng (not a cached first state).

    The returned state keeps the finished step's reward, done, metrics and truncation flag, while
    its world, physics and observations belong to the new episode. Works per env; `vmap` it.
    """

    def __init__(self, env: PursuitEvasionEnv):
        self.env = env

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def reset(self, rng: jax.Array) -> State:
        return self.env.reset(rng)

    def step(self, state: State, actions: dict[str, jax.Array]) -> State:
        stepped = self.env.step(state, actions)
        rng, reset_rng = jax.random.split(stepped.info["rng"])
        return self._restart_done(stepped, rng, self.env.reset(reset_rng))

    def step_batch(self, states: State, actions: dict[str, jax.Array]) -> State:
        """`jax.vmap(self.step)` over a batch of arenas, with the same result, but the fresh
        arenas are only drawn on steps where some arena finished.

        Under `vmap` a per-arena `lax.cond` runs both branches, so `step` pays for a full reset
        (the placement sampler) on every step; here one batch-level `lax.cond` skips it on the
        steps where no arena is done, which are most of them.
        """
        stepped = jax.vmap(self.env.step)(states, actions)
        keys = jax.vmap(jax.random.split)(stepped.info["rng"])
        rng, reset_rng = keys[:, 0], keys[:, 1]

        def restart() -> State:
            fresh = jax.vmap(self.env.reset)(reset_rng)
            return jax.vmap(self._restart_done)(stepped, rng, fresh)

        def keep() -> State:
            return stepped.replace(info={**stepped.info, "rng": rng})

        return jax.lax.cond(jnp.any(stepped.done > 0), restart, keep)

    @staticmethod
    def _restart_done(stepped: State, rng: jax.Array, fresh: State) -> State:
        """`stepped` with the world, physics and observations of `fresh` if it is done."""
        done = stepped.done > 0

        def pick(new, old):
            return jnp.where(done, new, old)

        world = jax.tree.map(pick, fresh.world, stepped.world)
        physics = jax.tree.map(pick, fresh.physics, stepped.physics)
        obs = jax.tree.map(pick, fresh.obs, stepped.obs)
        info = dict(stepped.info)
        info["rng"] = rng
        return stepped.replace(world=world, physics=physics, obs=obs, info=info)


def make(name_or_config: str | EnvConfig = "20-5-8", backend: str = "mjx") -> PursuitEvasionEnv:
    """Builds an env from a preset name or an `EnvConfig`."""
    if isinstance(name_or_config, str):
        return PursuitEvasionEnv(get_preset(name_or_config), backend=backend)
    if not isinstance(name_or_config, EnvConfig):  # None failed deep inside with AttributeError
        raise TypeError(
            f"make() takes a preset name or an EnvConfig, got {type(name_or_config).__name__}"
        )
    return PursuitEvasionEnv(name_or_config, backend=backend)
