"""Train the same experiment on the MJX and the kinematic backend and compare what they learn.

    python tools/compare_backends.py --out docs/data/backend_training.json

Both runs use one config (seed, budget, everything) but the backend; each trained policy is then
evaluated on its own backend against the scripted opponent with the same seeds, and the means
with 95% Student-t intervals are written to the JSON. Issue 9 asks that training on MJX match
the kinematic backend within these intervals.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import platform
import time
from pathlib import Path

import jax
import numpy as np
import tyro

from pe_mjx.episodes import play_episodes
from pe_mjx.evaluate import mean_ci
from pe_mjx.experiment import default_config
from pe_mjx.ppo.train import Trainer


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path = Path("docs/data/backend_training.json")
    preset: str = "4-1-2"
    iterations: int = 100
    """PPO iterations of 32 arenas x 32 steps."""
    trials: int = 128
    seed: int = 0


def run(backend: str, args: Args) -> dict:
    # The evaders' learning test setting (tests/ppo/test_train.py): 4-1-2 counts, a 4 m arena.
    config = default_config(args.preset).override(
        {
            "backend": backend,
            "pursuer.policy": "scripted",
            "env.arena.radius": 4.0,
            "ppo.num_envs": 32,
            "ppo.unroll_length": 32,
            "env_steps": 32 * 32 * args.iterations,
            "eval_envs": args.trials,
            "eval_every": 0,
            "seed": args.seed,
        }
    )
    trainer = Trainer(config)
    state = trainer.init()
    step = jax.jit(trainer.iteration, donate_argnums=0)
    tic = time.perf_counter()
    for _ in range(config.num_iterations):
        state, _ = step(state)
    seconds = time.perf_counter() - tic
    keys = jax.random.split(jax.random.key(123), args.trials)
    policies = trainer.policies(state)
    pair = {"evader": policies["evader"], "pursuer": trainer.scripted["pursuer"]}
    final = play_episodes(trainer.eval_env, pair, keys)
    out = {"backend": backend, "train_seconds": seconds, "env_steps": int(state.env_steps)}
    for name in ("length", "success_rate", "evader_distance"):
        mean, half = mean_ci(np.asarray(final.metrics[f"episode/{name}"]))
        out[name] = {"mean": mean, "ci95": half}
    return out


def main() -> None:
    args = tyro.cli(Args)
    results = [run(backend, args) for backend in ("kinematic", "mjx")]
    payload = {
        "date": datetime.date.today().isoformat(),
        "machine": f"{platform.machine()} {platform.processor() or ''}, CPU".strip(),
        "args": {k: str(v) for k, v in dataclasses.asdict(args).items()},
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    for r in results:
        print(
            f"{r['backend']:>9}: time to capture {r['length']['mean']:.1f} ± "
            f"{r['length']['ci95']:.1f}, success {r['success_rate']['mean']:.3f} ± "
            f"{r['success_rate']['ci95']:.3f} ({r['train_seconds']:.0f} s)"
        )


if __name__ == "__main__":
    main()
