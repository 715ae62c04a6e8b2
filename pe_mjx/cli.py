"""The `pe-mjx` command line: one entry point, one subcommand per job (typed configs via tyro)."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Annotated

import tyro

from pe_mjx.config import PRESETS
from pe_mjx.ppo.config import TrainConfig


def _fail(message: str) -> None:
    print(f"pe-mjx: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def _check_preset(name: str) -> None:
    if name not in PRESETS:
        _fail(f"unknown preset {name!r}; known presets: {', '.join(PRESETS)}")


@dataclasses.dataclass(frozen=True)
class SceneArgs:
    """Write the standalone MJCF of one preset's arena, exactly as `env.reset(key(seed))` draws it."""

    preset: str = "20-5-8"
    """Scenario preset (P-E-K)."""
    seed: int = 0
    """The seed given to `jax.random.key` for `env.reset`."""
    output: Annotated[Path, tyro.conf.arg(aliases=("-o",))] = Path("arena.xml")
    """Where to write the MJCF."""
    force: bool = False
    """Overwrite an existing output file."""


@dataclasses.dataclass(frozen=True)
class DemoArgs:
    """Play one scripted match (scripted pursuers against scripted evaders) and print the result."""

    preset: str = "8-2-4"
    seed: int = 0
    backend: str = "kinematic"
    steps: int = 1000
    """Control steps at most (the episode may end earlier)."""


@dataclasses.dataclass(frozen=True)
class TrainArgs:
    """Train a pursuer and an evader policy together (IPPO co-evolution), or one against a fixed
    opponent. Logs to <out>/tb (TensorBoard), checkpoints to <out>/checkpoints."""

    config: Annotated[TrainConfig, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=TrainConfig
    )
    out: Path | None = None
    """Run directory (default: runs/<pursuer_encoder>-<preset>)."""
    resume: Path | None = None
    """Continue the run in this directory where it stopped (its saved config is used; a
    non-default --env-steps extends the budget)."""
    stop_after: int | None = None
    """Stop (with a checkpoint) after this many iterations; resume later with --resume."""
    progress: bool = True
    """Show the progress bar."""


def run_train(args: TrainArgs) -> None:
    from pe_mjx.ppo.checkpoint import CheckpointError
    from pe_mjx.ppo.run import resume_config, train

    try:
        if args.resume is not None:
            budget = args.config.env_steps
            config = resume_config(
                args.resume, None if budget == TrainConfig().env_steps else budget
            )
            out = args.resume
        else:
            config = args.config
            out = args.out or Path("runs") / f"{config.pursuer_encoder}-{config.preset}"
        _, state = train(
            config, out, resume=args.resume is not None, progress=args.progress,
            stop_after=args.stop_after,
        )
    except CheckpointError as err:
        _fail(str(err))
    print(f"run {out}: {int(state.env_steps):,} env steps, iteration {int(state.iteration)}")


def run_scene(args: SceneArgs) -> None:
    _check_preset(args.preset)
    if args.output.exists() and not args.force:
        _fail(f"{args.output} exists; pass --force to overwrite it")
    if not args.output.parent.exists():
        _fail(f"directory {args.output.parent} does not exist")
    from pe_mjx.export import arena_xml

    xml = arena_xml(args.preset, args.seed)
    tmp = args.output.with_name(args.output.name + ".tmp")
    tmp.write_text(xml)
    tmp.replace(args.output)
    print(f"wrote {args.output} (preset {args.preset}, seed {args.seed})")


def run_demo(args: DemoArgs) -> None:
    _check_preset(args.preset)
    from pe_mjx.match import play_scripted_match

    result = play_scripted_match(args.preset, args.seed, args.backend, args.steps)
    for key, value in result.items():
        print(f"{key:>28s}: {value}")


def main(argv: list[str] | None = None) -> None:
    commands = {
        "scene": (SceneArgs, run_scene),
        "demo": (DemoArgs, run_demo),
        "train": (TrainArgs, run_train),
    }
    subcommands = {name: cls for name, (cls, _) in commands.items()}
    args = tyro.extras.subcommand_cli_from_dict(subcommands, args=argv, prog="pe-mjx")
    for cls, fn in commands.values():
        if isinstance(args, cls):
            try:
                fn(args)
            except ValueError as err:
                _fail(str(err))
            return


if __name__ == "__main__":
    main()
