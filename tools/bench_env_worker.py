"""The worker of tools/bench_env.py: measures one configuration in a process of its own.

    python tools/bench_env_worker.py SPEC_JSON

`tools/bench_env.py` starts this script once per configuration (never imports it: no tool imports
another), so that the worker's peak resident set size belongs to that configuration alone, and
reads its one result line, `BENCH_RESULT <json>`, from stdout. SPEC_JSON names the implementation
(`impl`: "jaxmarl", "kinematic", "mjx", or "breakdown"), the preset and the batch, and how to time
it.

What is timed: the full `env.step` (physics, events, observations with action masks, rewards and
metrics), `jit` of `vmap` over a batch of arenas, stepped `steps` times per call (bench_env's
`--steps`) under `jax.lax.scan`. Actions are random and valid: one uniform draw per agent over all
its actions, and a draw that the state's action mask forbids becomes a stop (v = 0, omega = 0);
`actions` "fixed" (`--actions fixed`) drives every agent straight at full speed. There is no
auto-reset; a step's cost does not depend on the state (everything is dense). The anchor is
JaxMARL's `MPE_simple_tag_v3` with the same counts (pursuers = adversaries, evaders = good agents,
obstacles = landmarks), random actions, its jitted `vmap`ped step (which includes its own
auto-reset) under the same scan, with observations and rewards kept in the carry so that XLA cannot
drop them.

The breakdown times the parts of a step separately (jitted, `vmap`ped, batch 256 at 20-5-8 unless
changed): the backend integrators, the shared geometry (offsets and distances), events, rewards,
observations without action masks, action masks, and the whole step, each part given its inputs
precomputed, as `step` hands them over.
"""

from __future__ import annotations

import functools
import json
import resource
import sys
import time
from typing import Any

RESULT_TAG = "BENCH_RESULT "  # the prefix tools/bench_env.py looks for


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _time_calls(fn, carry, min_calls: int, min_seconds: float, max_seconds: float):
    """Calls `carry = fn(carry)` until both minimums are met (or max_seconds); returns timings."""
    import jax

    times = []
    start = time.perf_counter()
    while True:
        t0 = time.perf_counter()
        carry = jax.block_until_ready(fn(carry))
        times.append(time.perf_counter() - t0)
        elapsed = time.perf_counter() - start
        if len(times) >= min_calls and elapsed >= min_seconds:
            break
        if len(times) >= 2 and elapsed >= max_seconds:
            break
    return times, carry


def _rollout_ours(preset: str, backend: str, batch: int, steps: int, actions: str):
    import jax
    import jax.numpy as jnp

    from pe_mjx.env import make

    env = make(preset, backend=backend)
    n_agents = env.num_agents
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch))

    straight, stop = {}, {}  # omega = 0 at full speed and at v = 0 (index = n_v N_omega + n_omega)
    for team in ("pursuer", "evader"):
        t = env.config.team(team)
        straight[team] = (t.num_speeds - 1) * t.num_turn_rates + t.num_turn_rates // 2
        stop[team] = t.num_turn_rates // 2

    def choose(key, state):
        out = {}
        for k, team in zip(jax.random.split(key, 2), ("pursuer", "evader"), strict=True):
            mask = state.obs[team]["action_mask"]
            if actions == "fixed":
                out[team] = jnp.full(mask.shape[:-1], straight[team], jnp.int32)
            else:
                # One uniform draw per agent over all actions, as cheap as JaxMARL's random
                # actions; one the mask forbids becomes a stop (v = 0, omega = 0), which the mask
                # always allows when no minimum turning radius is set. (Sampling from the masked
                # categorical instead costs more than the step itself on CPU.)
                pick = jax.random.randint(k, mask.shape[:-1], 0, mask.shape[-1])
                ok = jnp.take_along_axis(mask, pick[..., None], axis=-1)[..., 0]
                out[team] = jnp.where(ok, pick, stop[team])
        return out

    def rollout(carry):
        def body(c, _):
            state, key = c
            key, sub = jax.random.split(key)
            return (jax.vmap(env.step)(state, choose(sub, state)), key), None

        return jax.lax.scan(body, carry, None, length=steps)[0]

    return rollout, (states, jax.random.key(1)), n_agents


def _rollout_jaxmarl(preset: str, batch: int, steps: int):
    import jax
    import jax.numpy as jnp
    import jaxmarl

    from pe_mjx.config import get_preset

    cfg = get_preset(preset)
    env = jaxmarl.make(
        "MPE_simple_tag_v3",
        num_good_agents=cfg.evader.num_agents,
        num_adversaries=cfg.pursuer.num_agents,
        num_obs=cfg.arena.num_obstacles,
    )
    agents = list(env.agents)
    n_actions = jnp.asarray([env.action_space(a).n for a in agents])
    step = jax.vmap(env.step)
    obs, states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch))

    def random_actions(key):
        u = jax.random.uniform(key, (len(agents), batch))
        idx = jnp.floor(u * n_actions[:, None]).astype(jnp.int32)
        return {a: idx[i] for i, a in enumerate(agents)}

    zero = {a: jnp.zeros((batch,), jnp.int32) for a in agents}
    obs, states, rewards, _, _ = jax.jit(step)(
        jax.random.split(jax.random.key(2), batch), states, zero
    )

    def rollout(carry):
        def body(c, _):
            state, _, _, key = c
            key, k_act, k_step = jax.random.split(key, 3)
            o, s, r, _, _ = step(jax.random.split(k_step, batch), state, random_actions(k_act))
            return (s, o, r, key), None  # observations and rewards stay live (no DCE)

        return jax.lax.scan(body, carry, None, length=steps)[0]

    return rollout, (states, obs, rewards, jax.random.key(1)), len(agents)


def run_one(spec: dict[str, Any]) -> dict[str, Any]:
    """Measures one (impl, preset, batch); runs inside the worker subprocess."""
    import jax

    impl, preset, batch, steps = spec["impl"], spec["preset"], spec["batch"], spec["steps"]
    if impl == "jaxmarl":
        rollout, carry, n_agents = _rollout_jaxmarl(preset, batch, steps)
    else:
        rollout, carry, n_agents = _rollout_ours(preset, impl, batch, steps, spec["actions"])
    carry = jax.block_until_ready(carry)
    baseline = _rss_mb()
    t0 = time.perf_counter()
    compiled = jax.jit(rollout).lower(carry).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    carry = jax.block_until_ready(compiled(carry))  # first call: warm-up, not counted
    first_s = time.perf_counter() - t0
    times, _ = _time_calls(
        compiled, carry, spec["min_calls"], spec["min_seconds"], spec["max_seconds"]
    )
    work = batch * steps
    best, median = min(times), sorted(times)[len(times) // 2]
    return {
        "impl": impl,
        "preset": preset,
        "batch": batch,
        "status": "ok",
        "agents": n_agents,
        "steps_per_call": steps,
        "calls": len(times),
        "env_steps_per_s": work / best,
        "agent_steps_per_s": work * n_agents / best,
        "env_steps_per_s_median": work / median,
        "seconds_per_call_best": best,
        "seconds_per_call_median": median,
        "first_call_s": first_s,
        "compile_s": compile_s,
        "baseline_rss_mb": baseline,
        "peak_rss_mb": _rss_mb(),
    }


def mjx_before_issue_9(config):
    """The MJX env as it was before issue 9, for the breakdown's before/after rows: the same env
    code on the old physics model (`implicitfast`, automatic mass-matrix mode, velocity actuators
    with a 5 ms lag, 4 physics steps of 0.05 s per control step). Its chord commands are the new
    ones, which cost the same as the old midpoint commands."""
    import mujoco
    from mujoco import mjx

    from pe_mjx import scene
    from pe_mjx.env import PursuitEvasionEnv

    config = config.replace(physics_dt=0.05)
    env = PursuitEvasionEnv(config, backend="mjx")
    spec = scene.build_spec(config, None, visual=False)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.jacobian = mujoco.mjtJacobian.mjJAC_AUTO
    spec.option.disableflags = int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    for act in spec.actuators:  # deadbeat kv = inertia / physics_dt -> lagging inertia / 5 ms
        act.set_to_velocity(kv=act.gainprm[0] * config.physics_dt / 0.005)
    env.mj_model = spec.compile()
    env.mjx_model = mjx.put_model(env.mj_model)
    env.mjx_data0 = mjx.make_data(env.mjx_model)
    return env


def run_breakdown(spec: dict[str, Any]) -> dict[str, Any]:
    """Times the parts of one step (see the module docstring); runs in the worker subprocess."""
    from pe_mjx.env import make

    preset, batch, reps = spec["preset"], spec["batch"], spec["reps"]
    envs = {b: make(preset, backend=b) for b in ("kinematic", "mjx")}
    env = envs["kinematic"]
    before = mjx_before_issue_9(env.config)
    states, acts = _into_an_episode(envs, batch)
    rows = _time_interleaved(_step_parts(envs, before, states, acts), reps)
    return {
        "preset": preset,
        "batch": batch,
        "reps": reps,
        "agents": env.num_agents,
        "pursuers": env.num_pursuers,
        "parts": rows,
        "note": (
            "each part jitted and vmapped on its own, inputs precomputed as step hands them over "
            "(geometry is computed once per step and shared by events, rewards, observations and "
            "masks); per batched call; the remainder of a full step is glue (action lookup, "
            "freezing incapacitated agents, metrics, done flags)"
        ),
    }


def _masked_random(key, state) -> dict[str, Any]:
    """Uniformly random valid actions of both teams, per arena of a batched `state`."""
    import jax
    import jax.numpy as jnp

    ks = jax.random.split(key, 2)
    return {
        t: jax.random.categorical(k, jnp.where(state.obs[t]["action_mask"], 0.0, -jnp.inf))
        for k, t in zip(ks, ("pursuer", "evader"), strict=True)
    }


def _into_an_episode(envs: dict[str, Any], batch: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """Batched states of each backend's env 10 steps into an episode (some agents incapacitated),
    driven by the same random valid actions, and the actions of the next step."""
    import jax

    keys = jax.random.split(jax.random.key(0), batch)
    states = {b: jax.jit(jax.vmap(e.reset))(keys) for b, e in envs.items()}
    key = jax.random.key(1)
    steps = {b: jax.jit(jax.vmap(e.step)) for b, e in envs.items()}
    for _ in range(10):
        key, sub = jax.random.split(key)
        acts = _masked_random(sub, states["kinematic"])
        states = {b: steps[b](states[b], acts) for b in envs}
    return states, _masked_random(key, states["kinematic"])


def _step_parts(
    envs: dict[str, Any], before: Any, states: dict[str, Any], acts: dict[str, Any]
) -> dict[str, tuple[Any, tuple]]:
    """Name -> (function of one arena, its batched inputs as `step` hands them over)."""
    import jax
    import jax.numpy as jnp

    from pe_mjx.stages import dynamics, events, geometry, observations, rewards

    env = envs["kinematic"]
    config = env.config
    w = states["kinematic"].world
    physics_before = jax.vmap(lambda q: before.mjx_data0.replace(qpos=q))(
        states["mjx"].physics.qpos
    )
    state_before = states["mjx"].replace(physics=physics_before)
    speed = jnp.where(w.active, 0.1, 0.0)
    turn = jnp.where(w.active, 0.3, 0.0)
    geom = jax.jit(jax.vmap(geometry.geometry))(w.pos, w.yaw, w.obstacles)
    ev = jax.jit(jax.vmap(functools.partial(events.events, config)))(geom, w.active, w.obstacles)
    return {
        "physics (kinematic)": (
            functools.partial(dynamics.integrate_kinematic, config),
            (w.pos, w.yaw, speed, turn),
        ),
        "physics (mjx)": (
            functools.partial(dynamics.integrate_mjx, config, envs["mjx"].mjx_model),
            (states["mjx"].physics, speed, turn),
        ),
        "physics (mjx, before issue 9)": (
            functools.partial(dynamics.integrate_mjx, before.config, before.mjx_model),
            (physics_before, speed, turn),
        ),
        "geometry (shared offsets, distances)": (geometry.geometry, (w.pos, w.yaw, w.obstacles)),
        "events": (functools.partial(events.events, config), (geom, w.active, w.obstacles)),
        "rewards": (
            functools.partial(rewards.reward_terms, config),
            (geom, w.pos, w.pos, w.active, ev.active, ev.capture_pairs, w.obstacles),
        ),
        "observations (without masks)": (
            functools.partial(observations.entity_observations, config),
            (w, geom),
        ),
        "action masks": (
            functools.partial(observations.action_masks, config, env.mask_tables),
            (w, geom),
        ),
        "full step (kinematic)": (envs["kinematic"].step, (states["kinematic"], acts)),
        "full step (mjx)": (envs["mjx"].step, (states["mjx"], acts)),
        "full step (mjx, before issue 9)": (before.step, (state_before, acts)),
    }


def _time_interleaved(
    parts: dict[str, tuple[Any, tuple]], reps: int
) -> dict[str, dict[str, float]]:
    """Microseconds per call (best and median of `reps`) of `jit(vmap(fn))(*args)` for each part,
    compiled and warmed up first, then called in turns so that load spikes hit every part alike."""
    import jax
    import numpy as np

    compiled = {}
    for name, (fn, args) in parts.items():
        compiled[name] = jax.jit(jax.vmap(fn)).lower(*args).compile()
        jax.block_until_ready(compiled[name](*args))
    times: dict[str, list[float]] = {name: [] for name in parts}
    for _ in range(reps):
        for name, (_, args) in parts.items():
            t0 = time.perf_counter()
            jax.block_until_ready(compiled[name](*args))
            times[name].append(time.perf_counter() - t0)
    rows = {}
    for name, ts in times.items():
        rows[name] = {
            "us_best": 1e6 * float(np.min(ts)),
            "us_median": 1e6 * float(np.median(ts)),
        }
    return rows


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1 or argv[0] in ("-h", "--help"):
        print(
            "usage: python tools/bench_env_worker.py SPEC_JSON (tools/bench_env.py starts it)",
            file=sys.stderr,
        )
        return 2
    spec = json.loads(argv[0])
    try:
        out = run_breakdown(spec) if spec["impl"] == "breakdown" else run_one(spec)
    except ImportError as err:
        out = {"status": "skipped", "reason": f"import failed: {err}"}
    print(RESULT_TAG + json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
