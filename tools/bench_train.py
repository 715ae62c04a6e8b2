"""Training throughput per encoder, and where the time of an iteration goes.

    python tools/bench_train.py [--quick] [--out docs/bench_train.json]

For each encoder and preset it times, jitted and warmed up, in the same run:
  * the full training iteration (rollout + normalisation + GAE + PPO update of both teams);
  * the rollout alone with the learned policies (env steps + network forward passes);
  * the rollout with both teams scripted-free: uniformly random masked actions (env steps only).
Shares: env = env-only rollout; networks (forward) = rollout - env; update = iteration - rollout.
"Update alone allows" = env steps per iteration / update time: the throughput if the env and the
rollout cost nothing, a ceiling that only a faster PPO update can raise.
Results go to a JSON file and a Markdown table (printed, and pasted into docs/benchmarks.md).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import platform
import time
from pathlib import Path

import jax
import tyro

from pe_mjx.experiment import ExperimentConfig
from pe_mjx.names import ENCODERS
from pe_mjx.paper import paper_experiment
from pe_mjx.policy.scripted import make_policy
from pe_mjx.ppo.train import Trainer


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path = Path("docs/bench_train.json")
    quick: bool = False
    """Only 20-5-8 with the chosen encoders (and the reset ablation), no MJX, no large preset."""
    backend: str = "kinematic"
    """Env backend of the measured runs (mjx is measured for MIX at 20-5-8 in addition)."""
    repeats: int = 3
    encoders: tuple[str, ...] = ENCODERS
    """Encoders to measure."""
    peer: bool = True
    """Also time the peer trainer: a standard JAX IPPO (tools/peer_ippo.py, after JaxMARL's
    baseline) on JaxMARL's MPE simple_tag with 20 adversaries, 5 good agents and 8 obstacles,
    64 envs x 32 steps, 2 epochs x 4 minibatches (the `bench` extra: pip install
    'pe-mjx[bench]')."""
    reset_ablation: bool = True
    """Also time MIX with the env's reset computed on every step (`vmap(AutoResetWrapper.step)`)
    instead of only on steps where an arena finished (`step_batch`, what the trainer does)."""


def _time(fn, state, repeats: int) -> float:
    out = fn(state)
    jax.block_until_ready(out)
    best = float("inf")
    for _ in range(repeats):
        tic = time.perf_counter()
        jax.block_until_ready(fn(state))
        best = min(best, time.perf_counter() - tic)
    return best


def measure(config: ExperimentConfig, repeats: int, eager_reset: bool = False) -> dict:
    trainer = Trainer(config)
    if eager_reset:  # the ablation: a fresh arena drawn for every arena on every step
        trainer.env.step_batch = jax.vmap(trainer.env.step)
    state = trainer.init()
    tic = time.perf_counter()
    iteration = jax.jit(trainer.iteration)
    jax.block_until_ready(iteration(state))
    compile_s = time.perf_counter() - tic
    t_iter = _time(lambda s: iteration(s)[1], state, repeats)
    rollout = jax.jit(lambda s: trainer._rollout(s, s.rng)[1])
    t_roll = _time(rollout, state, repeats)
    # Env only: the same rollout machinery with random masked policies for both teams.
    saved = (trainer.learned, dict(trainer.fixed))
    trainer.learned = ()
    trainer.fixed = {t: make_policy("random", trainer.env_config, t) for t in ("pursuer", "evader")}
    env_only = jax.jit(lambda s: trainer._rollout(s, s.rng)[1]["done"])
    t_env = _time(env_only, state, repeats)
    trainer.learned, trainer.fixed = saved
    steps = config.steps_per_iteration
    agents = trainer.env_config.num_agents
    return {
        "preset": config.preset,
        "encoder": config.pursuer.network.encoder,
        "backend": config.backend,
        "num_envs": config.ppo.num_envs,
        "unroll_length": config.ppo.unroll_length,
        "reset": "every step" if eager_reset else "when done",
        "compile_s": compile_s,
        "env_steps_per_s": steps / t_iter,
        "agent_steps_per_s": steps * agents / t_iter,
        "share_env": t_env / t_iter,
        "share_forward": max(t_roll - t_env, 0.0) / t_iter,
        "share_update": max(t_iter - t_roll, 0.0) / t_iter,
        # The most this iteration could do if the env and the rollout's forward passes cost
        # nothing: what the PPO update alone allows.
        "update_bound_env_steps_per_s": steps / max(t_iter - t_roll, 1e-9),
    }


def measure_peer(num_envs: int, unroll: int, repeats: int) -> dict:
    """The peer IPPO's iteration on MPE simple_tag at 20-5-8 counts, timed like ours."""
    import sys

    from jaxmarl import make

    sys.path.insert(0, str(Path(__file__).parent))
    from peer_ippo import make_iteration

    env = make("MPE_simple_tag_v3", num_good_agents=5, num_adversaries=20, num_obs=8)
    init, iteration = make_iteration(env, num_envs, unroll)
    state = jax.jit(init)(jax.random.key(0))
    step = jax.jit(iteration)
    tic = time.perf_counter()
    jax.block_until_ready(step(state))
    compile_s = time.perf_counter() - tic
    t_iter = _time(lambda s: step(s)[1], state, repeats)
    steps = num_envs * unroll
    return {
        "preset": "MPE simple_tag 20-5-8",
        "encoder": "JaxMARL-style IPPO (MLP)",
        "backend": "jaxmarl",
        "num_envs": num_envs,
        "unroll_length": unroll,
        "reset": "auto (in step)",
        "compile_s": compile_s,
        "env_steps_per_s": steps / t_iter,
        "agent_steps_per_s": steps * len(env.agents) / t_iter,
        "share_env": None,
        "share_forward": None,
        "share_update": None,
        "update_bound_env_steps_per_s": None,
    }


def main() -> None:
    args = tyro.cli(Args)
    runs = []
    if args.peer:
        result = measure_peer(64, 32, args.repeats)
        print(json.dumps(result), flush=True)
        runs.append(result)
    plan = [("20-5-8", e, args.backend, 64, 32, False) for e in args.encoders]
    if args.reset_ablation:
        plan.append(("20-5-8", "mix", args.backend, 64, 32, True))
    if not args.quick:
        plan.append(("20-5-8", "mix", "mjx", 64, 32, False))
        plan += [("240-60-120", e, args.backend, 8, 16, False) for e in args.encoders]
    for preset, encoder, backend, num_envs, unroll, eager_reset in plan:
        config = paper_experiment(encoder, preset, backend=backend).override(
            {"ppo.num_envs": num_envs, "ppo.unroll_length": unroll, "eval_every": 0}
        )
        result = measure(config, args.repeats, eager_reset)
        print(json.dumps(result), flush=True)
        runs.append(result)
    machine = {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "jax": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
        "date": datetime.date.today().isoformat(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine, "runs": runs}, indent=1))
    print(table(runs, machine))


def table(runs: list[dict], machine: dict) -> str:
    lines = [
        f"Training throughput ({machine['devices'][0]}, {machine['cores']} cores, jax "
        f"{machine['jax']}, {machine['date']}); default network (width 32, 4 heads, hidden 64), "
        "PPO 2 epochs x 4 minibatches.",
        "",
        "| preset | encoder | backend | reset | envs x unroll | env-steps/s | agent-steps/s | "
        "env | forward | update | update alone allows | compile s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def share(x):
        return "-" if x is None else f"{x:.0%}"

    def bound(r):  # rows of files written before the column existed have none
        x = r.get("update_bound_env_steps_per_s")
        return "-" if x is None else f"{x:,.0f}"

    for r in runs:
        lines.append(
            f"| {r['preset']} | {r['encoder']} | {r['backend']} | {r['reset']} | {r['num_envs']}x"
            f"{r['unroll_length']} | {r['env_steps_per_s']:,.0f} | {r['agent_steps_per_s']:,.0f} "
            f"| {share(r['share_env'])} | {share(r['share_forward'])} | {share(r['share_update'])} "
            f"| {bound(r)} | {r['compile_s']:.0f} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
