"""Launch (or resume) the paper's co-evolutions: `python train/launch.py [--only NAME ...]`.

Every run goes to `<runs>/<encoder>-<preset>`; a run that already has a checkpoint is resumed, so
the command can be repeated (for example in 10-minute chunks with --stop-after) until all finish.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import tyro

from pe_mjx.paper import ENV_STEPS, paper_runs
from pe_mjx.policy import store
from pe_mjx.ppo.run import train


@dataclasses.dataclass(frozen=True)
class Args:
    """Train the paper's twelve co-evolutions (4 encoders x 3 scales)."""

    runs: Path = Path("runs")
    """Parent directory of the run directories."""
    only: tuple[str, ...] = ()
    """Run names to train (default: all twelve), e.g. mix-20-5-8."""
    env_steps: int = ENV_STEPS
    """Budget per run (the paper: 10 million)."""
    backend: Literal["mjx", "kinematic"] = "mjx"
    seed: int = 0
    stop_after: int | None = None
    """Iterations per run in this call (then checkpoint and move on); None: to the end."""


def main() -> None:
    args = tyro.cli(Args)
    configs = paper_runs(args.env_steps, args.backend, args.seed)
    unknown = set(args.only) - set(configs)
    if unknown:
        raise SystemExit(f"unknown runs {sorted(unknown)}; known: {', '.join(configs)}")
    for name, config in configs.items():
        if args.only and name not in args.only:
            continue
        out = args.runs / name
        resume = (out / store.CHECKPOINT_DIR).exists()
        if resume and store.read_meta(out)["env_steps"] >= config.env_steps:
            print(f"{name}: done")
            continue
        print(f"{name}: {'resuming' if resume else 'starting'} in {out}")
        train(config, out, resume=resume, stop_after=args.stop_after)


if __name__ == "__main__":
    main()
