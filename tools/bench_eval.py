"""What the in-training evaluation costs, per encoder: its share of a run's wall time.

    python tools/bench_eval.py [--presets 20-5-8] [--out docs/bench_eval.json]

For each encoder it times, in the same run and jitted and warmed up, one training iteration and
one `Trainer.evaluate` (each learned team plays `eval_envs` full episodes against the scripted
opponent) with fresh parameters, then gives the evaluation's share of the wall time,
`eval / (eval + eval_every * iteration)`, for several `eval_every`. Fresh pursuers never catch, so
their episodes last the whole `max_steps`: the figures are an upper bound of what a trained run
pays (its own share is logged as `perf/eval_share` in TensorBoard).

It also times one step of each scripted policy over 32 arenas (the evaluation's opponents) as
shipped and with `jnp.linalg.norm` in place of `pe_mjx.policy.scripted._norm`, the form they had
before 2026-12-02, so that the speed-up is measured in one run.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import tyro

from pe_mjx import bench
from pe_mjx.bench import best_of
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.experiment import ExperimentConfig
from pe_mjx.names import ENCODERS
from pe_mjx.paper import paper_experiment
from pe_mjx.policy import scripted
from pe_mjx.ppo.train import Trainer


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path = Path("docs/bench_eval.json")
    presets: tuple[str, ...] = ("20-5-8",)
    encoders: tuple[str, ...] = ENCODERS
    eval_envs: tuple[int, ...] = (16, 32)
    eval_every: tuple[int, ...] = (20, 40, 100)
    backend: str = "kinematic"
    repeats: int = 2


def measure(config: ExperimentConfig, args: Args) -> dict:
    trainer = Trainer(config)
    state = trainer.init()
    iteration = jax.jit(trainer.iteration)
    t_iter = best_of(lambda: iteration(state)[1], repeats=args.repeats).wall
    row = {
        "preset": config.preset,
        "encoder": config.pursuer.network.encoder,
        "iteration_s": t_iter,
        "env_steps_per_iteration": config.steps_per_iteration,
        "eval_s": {},
        "share": {},
    }
    key = jax.random.key(1)
    for envs in args.eval_envs:
        evaluator = Trainer(config.replace(eval_envs=envs))
        evaluate = jax.jit(evaluator.evaluate)
        t_eval = best_of(lambda ev=evaluate: ev(state, key), repeats=args.repeats).wall
        row["eval_s"][str(envs)] = t_eval
        row["share"][str(envs)] = {
            str(every): t_eval / (t_eval + every * t_iter) for every in args.eval_every
        }
    return row


def scripted_ms(preset: str, backend: str, repeats: int) -> dict:
    """Milliseconds per call of each scripted policy on 32 arenas, per distance form."""
    config = paper_experiment("mix", preset, backend=backend)
    env = PursuitEvasionEnv(config.env, backend=backend)
    keys = jax.random.split(jax.random.key(0), 32)
    obs = jax.vmap(env.reset)(keys).obs
    shipped = scripted._norm
    forms = {"per component": shipped, "linalg.norm": lambda v: jnp.linalg.norm(v, axis=-1)}
    out: dict = {"preset": preset, "arenas": 32}
    try:
        for form, norm in forms.items():
            scripted._norm = norm  # read when the policy is traced
            for team in ("pursuer", "evader"):
                policy = scripted.make_policy("scripted", config.env, team)
                step = jax.jit(lambda o, k, p=policy: jax.vmap(p)(o, k))
                seconds = best_of(lambda s=step, t=team: s(obs[t], keys), repeats=10 * repeats).wall
                out[f"{team} ({form})"] = 1000 * seconds
    finally:
        scripted._norm = shipped
    return out


def main() -> None:
    args = tyro.cli(Args)
    scripted = [scripted_ms(p, args.backend, args.repeats) for p in args.presets]
    print(json.dumps(scripted), flush=True)
    rows = []
    for preset in args.presets:
        for encoder in args.encoders:
            config = paper_experiment(encoder, preset, backend=args.backend)
            row = measure(config, args)
            print(json.dumps(row), flush=True)
            rows.append(row)
    machine = bench.machine()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    payload = {"machine": machine, "runs": rows, "scripted_policy_ms": scripted}
    args.out.write_text(json.dumps(payload, indent=1))
    print(table(rows, args))


def table(rows: list[dict], args: Args) -> str:
    heads = [f"{n} envs, every {e}" for n in args.eval_envs for e in args.eval_every]
    lines = [
        "| preset | encoder | iteration s | "
        + " | ".join(f"eval s ({n} envs)" for n in args.eval_envs)
        + " | "
        + " | ".join(heads)
        + " |",
        "|---" * (3 + len(args.eval_envs) + len(heads)) + "|",
    ]
    for r in rows:
        evals = " | ".join(f"{r['eval_s'][str(n)]:.1f}" for n in args.eval_envs)
        shares = " | ".join(
            f"{r['share'][str(n)][str(e)]:.0%}" for n in args.eval_envs for e in args.eval_every
        )
        lines.append(
            f"| {r['preset']} | {r['encoder']} | {r['iteration_s']:.2f} | {evals} | {shares} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    main()
