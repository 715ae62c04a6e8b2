"""Env-step throughput: pe-mjx's `env.step` (both backends) against JaxMARL's MPE simple tag.

    .venv/bin/python tools/bench_env.py [--quick] [--out docs/bench_env.json]
        [--markdown docs/benchmarks.md]

What is timed: the full `env.step` (physics, events, observations with action masks, rewards and
metrics), `jit` of `vmap` over a batch of arenas, stepped `--steps` times per call under
`jax.lax.scan`. Actions are random and valid: one uniform draw per agent over all its actions, and
a draw that the state's action mask forbids becomes a stop (v = 0, omega = 0); `--actions fixed`
drives every agent straight at full speed. There is no auto-reset; a step's cost does not depend on
the state (everything is dense). The anchor is JaxMARL's `MPE_simple_tag_v3` with the same counts
(pursuers = adversaries, evaders = good agents, obstacles = landmarks), random actions, its jitted
`vmap`ped step (which includes its own auto-reset) under the same scan, with observations and
rewards kept in the carry so that XLA cannot drop them. JaxMARL is the `bench` extra
(`pip install -e ".[bench]"`); without it those rows are recorded as skipped.

Each (implementation, preset, batch) runs in its own subprocess, so that its peak resident set size
(`resource.getrusage(RUSAGE_SELF).ru_maxrss`, which includes the ~0.5 GB of Python, JAX and XLA
loaded before anything is built; reported separately as `baseline_rss_mb`) belongs to it alone.
Configurations predicted, from the smaller batches of the same implementation, to need more than
`--max-seconds-total` are skipped and recorded with the reason. Memory is never predicted into a
skip: every configuration runs, and the parent polls its worker's resident memory and stops it
(recorded with the measured size) once it exceeds `--max-memory-gb`, or once it runs past the hard
`--timeout`. Throughput is the best of the timed calls (the machine
is shared and noisy: the best call is the least disturbed one); the median is in the JSON too.
Implementations run interleaved per batch size, so the ours/JaxMARL ratios come from the same
minutes of the same run.

The breakdown times the parts of a step separately (jitted, `vmap`ped, batch 256 at 20-5-8 unless
changed): the backend integrators, the shared geometry (offsets and distances), events, rewards,
observations without action masks, action masks, and the whole step, each part given its inputs
precomputed, as `step` hands them over.

`--quick` is a smoke run (small batches, few calls) that writes `results/bench_env_quick.json` and
no Markdown unless told otherwise.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import importlib.metadata
import importlib.util
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PRESETS = ("20-5-8", "240-60-120")
BATCHES = (1, 16, 256, 4096)
IMPLS = ("jaxmarl", "kinematic", "mjx")
SECTION = "## Env step throughput"
RESULT_TAG = "BENCH_RESULT "


# ----------------------------------------------------------------------------- worker side


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
    import jax
    import jax.numpy as jnp
    import numpy as np

    from pe_mjx.env import make
    from pe_mjx.stages import dynamics, events, geometry, observations, rewards

    preset, batch, reps = spec["preset"], spec["batch"], spec["reps"]

    envs = {b: make(preset, backend=b) for b in ("kinematic", "mjx")}
    env = envs["kinematic"]
    config = env.config
    before = mjx_before_issue_9(config)
    p, n = env.num_pursuers, env.num_agents

    # A state some steps into an episode (some agents incapacitated), for both backends.
    keys = jax.random.split(jax.random.key(0), batch)
    states = {b: jax.jit(jax.vmap(e.reset))(keys) for b, e in envs.items()}
    key = jax.random.key(1)
    steps = {b: jax.jit(jax.vmap(e.step)) for b, e in envs.items()}

    def masked_random(key, state):
        ks = jax.random.split(key, 2)
        return {
            t: jax.random.categorical(k, jnp.where(state.obs[t]["action_mask"], 0.0, -jnp.inf))
            for k, t in zip(ks, ("pursuer", "evader"), strict=True)
        }

    for _ in range(10):
        key, sub = jax.random.split(key)
        acts = masked_random(sub, states["kinematic"])
        states = {b: steps[b](states[b], acts) for b in envs}
    acts = masked_random(key, states["kinematic"])
    w = states["kinematic"].world
    physics_before = jax.vmap(lambda q: before.mjx_data0.replace(qpos=q))(
        states["mjx"].physics.qpos
    )
    state_before = states["mjx"].replace(physics=physics_before)
    speed = jnp.where(w.active, 0.1, 0.0)
    turn = jnp.where(w.active, 0.3, 0.0)
    geom = jax.jit(jax.vmap(geometry.geometry))(w.pos, w.yaw, w.obstacles)
    ev = jax.jit(jax.vmap(functools.partial(events.events, config)))(geom, w.active, w.obstacles)

    parts = {
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
    compiled = {}
    for name, (fn, args) in parts.items():
        compiled[name] = jax.jit(jax.vmap(fn)).lower(*args).compile()
        jax.block_until_ready(compiled[name](*args))
    times: dict[str, list[float]] = {name: [] for name in parts}
    for _ in range(reps):  # interleaved, so that load spikes hit every part alike
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
    return {
        "preset": preset,
        "batch": batch,
        "reps": reps,
        "agents": n,
        "pursuers": p,
        "parts": rows,
        "note": (
            "each part jitted and vmapped on its own, inputs precomputed as step hands them over "
            "(geometry is computed once per step and shared by events, rewards, observations and "
            "masks); per batched call; the remainder of a full step is glue (action lookup, "
            "freezing incapacitated agents, metrics, done flags)"
        ),
    }


def worker_main(spec: dict[str, Any]) -> None:
    try:
        out = run_breakdown(spec) if spec["impl"] == "breakdown" else run_one(spec)
    except ImportError as err:
        out = {"status": "skipped", "reason": f"import failed: {err}"}
    print(RESULT_TAG + json.dumps(out), flush=True)


# ----------------------------------------------------------------------------- parent side


def machine_info() -> dict[str, Any]:
    import jax
    import jaxlib
    import mujoco

    cpu = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    info = {
        "cpu_model": cpu,
        "cpu_cores": os.cpu_count(),
        "memory_gb": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "jax_backend": jax.default_backend(),
        "mujoco": mujoco.__version__,
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "load_average_at_start": list(os.getloadavg()),
    }
    info["jaxmarl"] = _jaxmarl_version()
    return info


def _jaxmarl_version() -> str | None:
    """JaxMARL's installed version, or None (without importing it: that is slow and noisy)."""
    if importlib.util.find_spec("jaxmarl") is None:
        return None
    return importlib.metadata.version("jaxmarl")


def _rss_of(pid: int) -> float:
    """Resident set size of a live process in MB (Linux /proc), 0 if it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def run_worker(spec: dict[str, Any], timeout: float, max_memory_gb: float) -> dict[str, Any]:
    """Runs one configuration in a subprocess, stopping it past `timeout` seconds or once its
    measured resident memory exceeds `max_memory_gb` (polled every 0.1 s)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(spec)]
    env = dict(os.environ)
    env.setdefault("PYTHONPATH", str(ROOT))
    limit_mb = max_memory_gb * 1024
    peak = 0.0
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, cwd=ROOT, env=env)
        start = time.monotonic()
        reason = None
        while proc.poll() is None:
            peak = max(peak, _rss_of(proc.pid))
            if peak > limit_mb:
                reason = (
                    f"stopped at a measured {peak / 1024:.1f} GB resident > --max-memory-gb "
                    f"{max_memory_gb:g}"
                )
            elif time.monotonic() - start > timeout:
                reason = f"ran past the {timeout:.0f} s timeout"
            if reason:
                proc.kill()
                proc.wait()
                return {"status": "skipped", "reason": reason}
            time.sleep(0.1)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    for line in stdout.splitlines():
        if line.startswith(RESULT_TAG):
            return json.loads(line[len(RESULT_TAG) :])
    tail = (stderr or stdout).strip().splitlines()[-3:]
    if proc.returncode < 0 or proc.returncode == 137:
        reason = f"worker killed (signal {-proc.returncode}), probably out of memory"
    else:
        reason = f"worker failed (exit {proc.returncode}): {' | '.join(tail)}"
    return {"status": "skipped", "reason": reason}


def predict(
    history: list[dict[str, Any]], batch: int, args: argparse.Namespace
) -> dict[str, float]:
    """Steps per call, peak memory (MB) and wall time (s) of `batch`, from smaller batches.

    Time per env-step does not grow with the batch (it usually shrinks), so scaling the last
    measurement linearly is an upper bound. Memory grows linearly beyond the baseline: with two
    measurements their slope is used, with one everything above the baseline is assumed to scale
    (an overestimate, hence safe). Calls longer than `--max-call-seconds` get fewer steps.
    """
    ok = [r for r in history if r.get("status") == "ok"]
    if not ok:
        return {}
    last = ok[-1]
    if len(ok) >= 2:
        prev = ok[-2]
        slope = max(last["peak_rss_mb"] - prev["peak_rss_mb"], 0.0) / (
            last["batch"] - prev["batch"]
        )
    else:
        slope = (last["peak_rss_mb"] - last["baseline_rss_mb"]) / last["batch"]
    memory = last["peak_rss_mb"] + slope * (batch - last["batch"])
    per_env_step = last["seconds_per_call_best"] / (last["batch"] * last["steps_per_call"])
    steps = args.steps
    if per_env_step * batch * steps > args.max_call_seconds:
        steps = max(args.min_steps, int(args.max_call_seconds / (per_env_step * batch)))
    per_call = per_env_step * batch * steps
    timed = max(2 * per_call, min(args.min_calls * per_call, args.max_seconds))
    seconds = last["compile_s"] + per_call + timed  # compile, warm-up call, timed calls
    return {
        "steps": steps,
        "memory_mb": memory,
        "seconds": seconds,
        "seconds_per_call": per_call,
    }


def collect(args: argparse.Namespace) -> dict[str, Any]:
    have_jaxmarl = _jaxmarl_version() is not None
    results: list[dict[str, Any]] = []
    history: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for preset in args.presets:
        for batch in args.batches:
            for impl in args.impls:
                if impl == "jaxmarl" and preset not in args.jaxmarl_presets:
                    continue
                hist = history.setdefault((impl, preset), [])
                guess = predict(hist, batch, args)
                spec = {
                    "impl": impl,
                    "preset": preset,
                    "batch": batch,
                    "steps": int(guess.get("steps", args.steps)),
                    "actions": args.actions,
                    "min_calls": args.min_calls,
                    "min_seconds": args.min_seconds,
                    "max_seconds": args.max_seconds,
                }
                reason = None
                if impl == "jaxmarl" and not have_jaxmarl:
                    reason = "jaxmarl is not installed (pip install -e '.[bench]')"
                elif any(r.get("status") != "ok" for r in hist):
                    reason = "a smaller batch of this implementation was skipped"
                elif guess and guess["seconds"] > args.max_seconds_total:
                    reason = (
                        f"predicted {guess['seconds']:.0f} s (compile, then calls of "
                        f"{guess['seconds_per_call']:.1f} s for {spec['steps']} steps) > "
                        f"{args.max_seconds_total:g} s"
                    )
                if reason is None:
                    print(f"[bench_env] {impl:9s} {preset:10s} batch {batch:5d} ...", flush=True)
                    row = run_worker(spec, args.timeout, args.max_memory_gb)
                else:
                    row = {"status": "skipped", "reason": reason}
                row = {"impl": impl, "preset": preset, "batch": batch, **row}
                if guess:
                    row["predicted"] = {k: round(v, 2) for k, v in guess.items()}
                hist.append(row)
                results.append(row)
                if row["status"] == "ok":
                    print(
                        f"[bench_env] {impl:9s} {preset:10s} batch {batch:5d}: "
                        f"{row['env_steps_per_s']:12,.0f} env-steps/s, "
                        f"compile {row['compile_s']:.1f} s, peak {row['peak_rss_mb']:.0f} MB",
                        flush=True,
                    )
                else:
                    print(
                        f"[bench_env] {impl:9s} {preset:10s} batch {batch:5d}: skipped, "
                        f"{row['reason']}",
                        flush=True,
                    )
    return {"results": results, "ratios": ratios(results)}


def ratios(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    ok = {(r["impl"], r["preset"], r["batch"]): r for r in results if r["status"] == "ok"}
    out = []
    for (impl, preset, batch), row in sorted(ok.items()):
        anchor = ok.get(("jaxmarl", preset, batch))
        if impl == "jaxmarl" or anchor is None:
            continue
        out.append(
            {
                "backend": impl,
                "preset": preset,
                "batch": batch,
                "ours_env_steps_per_s": row["env_steps_per_s"],
                "jaxmarl_env_steps_per_s": anchor["env_steps_per_s"],
                "ratio_ours_over_jaxmarl": row["env_steps_per_s"] / anchor["env_steps_per_s"],
                "ratio_median": row["env_steps_per_s_median"] / anchor["env_steps_per_s_median"],
            }
        )
    return out


# ----------------------------------------------------------------------------- markdown


def _fmt(x: float) -> str:
    return f"{x:,.0f}"


def markdown(report: dict[str, Any]) -> str:
    m = report["machine"]
    s = report["settings"]
    lines = [
        SECTION,
        "",
        f"Generated by `tools/bench_env.py` on {m['date']}: {m['cpu_model']}, {m['cpu_cores']} "
        f"cores, {m['memory_gb']} GB, jax {m['jax']} ({m['jax_backend']}), mujoco {m['mujoco']}, "
        f"JaxMARL {m.get('jaxmarl') or 'not installed'}. Load average at start: "
        f"{', '.join(f'{x:.1f}' for x in m['load_average_at_start'])} (the machine is shared).",
        "",
        "Full `env.step` (observations, action masks, rewards, metrics), `jit(vmap)` over the "
        "batch, stepped under `lax.scan` (steps per call in the table), "
        f"{s['actions']} valid actions; env-steps/s is the best timed call (median in the JSON). "
        "JaxMARL is `MPE_simple_tag_v3` with the same counts (adversaries = pursuers, good "
        "agents = evaders, landmarks = obstacles), random actions, its step (with auto-reset) "
        f"under the same scan, measured in the same run at {', '.join(s['jaxmarl_presets'])}; "
        "the ratio is ours / JaxMARL. Peak memory is the worker process's `ru_maxrss` "
        "(includes the Python/JAX baseline, ~0.4 GB). Raw numbers: `docs/bench_env.json`.",
        "",
        "| preset | batch | backend | env-steps/s | agent-steps/s | JaxMARL env-steps/s "
        "| ours / JaxMARL | steps/call | compile s | peak RSS MB |",
        "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    res = {(r["impl"], r["preset"], r["batch"]): r for r in report["results"]}
    skipped = []
    for preset in s["presets"]:
        for batch in s["batches"]:
            anchor = res.get(("jaxmarl", preset, batch), {})
            for impl in ("mjx", "kinematic"):
                row = res.get((impl, preset, batch))
                if row is None:
                    continue
                if row["status"] != "ok":
                    skipped.append(f"{impl} {preset} batch {batch}: {row['reason']}")
                    jm = _fmt(anchor["env_steps_per_s"]) if anchor.get("status") == "ok" else "-"
                    lines.append(f"| {preset} | {batch} | {impl} | skipped | | {jm} | | | | |")
                    continue
                if anchor.get("status") == "ok":
                    jm = _fmt(anchor["env_steps_per_s"])
                    ratio = f"{row['env_steps_per_s'] / anchor['env_steps_per_s']:.2f}"
                else:
                    jm, ratio = "-", "-"
                lines.append(
                    f"| {preset} | {batch} | {impl} | {_fmt(row['env_steps_per_s'])} | "
                    f"{_fmt(row['agent_steps_per_s'])} | {jm} | {ratio} | "
                    f"{row['steps_per_call']} | {row['compile_s']:.1f} | {row['peak_rss_mb']:.0f} |"
                )
            if anchor and anchor.get("status") != "ok":
                skipped.append(f"jaxmarl {preset} batch {batch}: {anchor['reason']}")
    if skipped:
        lines += ["", "Skipped:", ""] + [f"- {x}" for x in skipped]
    bd = report.get("breakdown")
    if bd and "parts" in bd:
        lines += [
            "",
            f"### Where a step's time goes ({bd['preset']}, batch {bd['batch']})",
            "",
            "Each part jitted and `vmap`ped on its own, with its inputs precomputed as `step` "
            "hands them over (the geometry, offsets and distances, is computed once per step and "
            "shared by events, rewards, observations and masks); microseconds per batched call, "
            f"best of {bd['reps']} interleaved calls. Parts run alone lose some fusion (the "
            "geometry alone writes all its arrays out; in a step they are fused into their "
            "consumers), so they need not add up to the step; the rest of a step is glue (action "
            "lookup, freezing incapacitated agents, metrics, done flags). The rows 'before "
            "issue 9' are the same env code on the old MJX model (`implicitfast`, 5 ms actuator "
            "lag, 4 physics steps per control step), measured in the same run; their share is of "
            "the old MJX step.",
            "",
            "| part | us per call (best) | us (median) | share of kinematic step "
            "| share of MJX step |",
            "| --- | ---: | ---: | ---: | ---: |",
        ]
        parts = bd["parts"]
        full = {b: parts[f"full step ({b})"]["us_best"] for b in ("kinematic", "mjx")}
        old_step = parts.get("full step (mjx, before issue 9)", {}).get("us_best")
        for name, row in parts.items():
            shares = []
            for b in ("kinematic", "mjx"):
                other = "mjx" if b == "kinematic" else "kinematic"
                total = full[b]
                if "before issue 9" in name:
                    mine, total = b == "mjx", old_step
                else:
                    mine = other not in name
                shares.append(f"{100 * row['us_best'] / total:.1f}%" if mine else "")
            lines.append(
                f"| {name} | {row['us_best']:,.0f} | {row['us_median']:,.0f} | "
                f"{shares[0]} | {shares[1]} |"
            )
    return "\n".join(lines) + "\n"


def write_markdown(path: Path, section: str) -> None:
    """Replaces this tool's section of `path` (or appends it); the rest of the file is kept."""
    if path.exists():
        text = path.read_text()
        start = text.find(SECTION)
        if start >= 0:
            nxt = text.find("\n## ", start + len(SECTION))
            end = len(text) if nxt < 0 else nxt + 1
            text = text[:start] + section + ("\n" if nxt >= 0 else "") + text[end:]
        else:
            text = text.rstrip("\n") + "\n\n" + section
    else:
        text = "# Benchmarks\n\n" + section
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


# ----------------------------------------------------------------------------- CLI


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: small batches, few calls")
    ap.add_argument("--out", type=Path, help="JSON results (default docs/bench_env.json)")
    ap.add_argument("--markdown", type=Path, help="Markdown file (default docs/benchmarks.md)")
    ap.add_argument("--no-markdown", action="store_true", help="write no Markdown")
    ap.add_argument("--presets", nargs="+", default=list(PRESETS))
    ap.add_argument("--batches", nargs="+", type=int)
    ap.add_argument("--impls", nargs="+", choices=IMPLS, default=list(IMPLS))
    ap.add_argument("--steps", type=int, help="env steps per call, under lax.scan (default 20)")
    ap.add_argument("--actions", choices=("random", "fixed"), default="random")
    ap.add_argument("--min-calls", type=int, help="timed calls per configuration (default 5)")
    ap.add_argument("--min-seconds", type=float, default=3.0, help="timed seconds at least")
    ap.add_argument("--max-seconds", type=float, default=60.0, help="stop timing after this")
    ap.add_argument("--max-call-seconds", type=float, default=10.0, help="fewer steps beyond")
    ap.add_argument("--min-steps", type=int, default=5, help="fewest steps per call")
    ap.add_argument(
        "--jaxmarl-presets",
        nargs="+",
        default=["20-5-8"],
        help="presets JaxMARL runs at (at 240-60-120 its compile ran past 300 s)",
    )
    ap.add_argument(
        "--max-memory-gb", type=float, default=16.0, help="stop a worker past this resident size"
    )
    ap.add_argument(
        "--max-seconds-total", type=float, default=120.0, help="skip configs predicted longer"
    )
    ap.add_argument("--timeout", type=float, default=180.0, help="hard limit per configuration")
    ap.add_argument("--breakdown-batch", type=int, help="batch of the breakdown (default 256)")
    ap.add_argument("--breakdown-preset", default="20-5-8")
    ap.add_argument("--no-breakdown", action="store_true")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    quick = args.quick
    if args.batches is None:
        args.batches = [1, 16] if quick else list(BATCHES)
    if args.steps is None:
        args.steps = 5 if quick else 20
    if args.min_calls is None:
        args.min_calls = 2 if quick else 5
    if quick:
        args.min_seconds = min(args.min_seconds, 0.5)
    if args.breakdown_batch is None:
        args.breakdown_batch = 16 if quick else 256
    if args.out is None:
        args.out = ROOT / ("results/bench_env_quick.json" if quick else "docs/bench_env.json")
    if args.markdown is None and not quick and not args.no_markdown:
        args.markdown = ROOT / "docs/benchmarks.md"
    if args.no_markdown:
        args.markdown = None
    for name in ("steps", "min_calls", "breakdown_batch"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if any(b < 1 for b in args.batches):
        ap.error("--batches must all be >= 1")
    from pe_mjx.config import PRESETS as KNOWN

    for preset in [*args.presets, *args.jaxmarl_presets, args.breakdown_preset]:
        if preset not in KNOWN:
            ap.error(f"unknown preset {preset!r}; known: {', '.join(KNOWN)}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.worker:
        worker_main(json.loads(args.worker))
        return 0
    start = time.perf_counter()
    report: dict[str, Any] = {"machine": machine_info()}
    report["settings"] = {
        "presets": args.presets,
        "batches": args.batches,
        "impls": args.impls,
        "steps_per_call": args.steps,
        "max_call_seconds": args.max_call_seconds,
        "jaxmarl_presets": args.jaxmarl_presets,
        "actions": args.actions,
        "min_calls": args.min_calls,
        "min_seconds": args.min_seconds,
        "max_memory_gb": args.max_memory_gb,
        "max_seconds_total": args.max_seconds_total,
        "timeout_s": args.timeout,
        "quick": args.quick,
        "throughput": "best timed call (median also given); calls after a warm-up call",
        "memory": (
            "peak_rss_mb: resource.getrusage(RUSAGE_SELF).ru_maxrss of the worker subprocess "
            "that runs only this configuration (includes the Python/JAX/XLA baseline); "
            "baseline_rss_mb: the same before compiling the rollout"
        ),
        "compile": "jax.jit(rollout).lower(...).compile() wall time",
    }
    report.update(collect(args))
    if not args.no_breakdown:
        spec = {
            "impl": "breakdown",
            "preset": args.breakdown_preset,
            "batch": args.breakdown_batch,
            "reps": 10 if args.quick else 50,
        }
        print("[bench_env] breakdown ...", flush=True)
        report["breakdown"] = run_worker(spec, args.timeout, args.max_memory_gb)
    report["total_seconds"] = round(time.perf_counter() - start, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"[bench_env] wrote {args.out}")
    if args.markdown:
        write_markdown(args.markdown, markdown(report))
        print(f"[bench_env] wrote {args.markdown}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
