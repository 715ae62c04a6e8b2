"""`pe-mjx plot`: a run's learning curves, or a replay as a picture or an animation."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro

from pe_mjx import outputs
from pe_mjx.commands.common import fail


@dataclasses.dataclass(frozen=True)
class PlotArgs:
    """Plot a run's learning curves (success against the scripted teams, per-team returns), or a
    replay written by `pe-mjx evaluate` as a top-down trajectory plot (the paper's Fig. 4) or,
    with -o x.gif / x.mp4, as an animation."""

    path: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN|REPLAY.npz")]
    """A `pe-mjx train` run directory, or a trajectory .npz (results/*/trajectories/)."""
    output: Annotated[Path | None, tyro.conf.arg(aliases=("-o",))] = None
    """File to write: .png (default <run>/learning_curve.png or <replay>.png); for a replay
    also .gif or .mp4 (an animation; MP4 needs the video extra)."""
    arena: int = 0
    """Which recorded arena of a replay to draw."""
    fps: int = 10
    """Frames per second of an animation (1 to 100)."""
    force: bool = False
    """Overwrite an existing output file."""


def run_plot(args: PlotArgs) -> None:
    from pe_mjx import plots

    try:
        plots.check_fps(args.fps)  # before anything is read
    except ValueError as err:
        fail(str(err))
    if args.output is not None and not args.output.parent.is_dir():
        fail(f"--output: directory {args.output.parent} does not exist")
    if args.path.is_dir():
        if args.output is not None and args.output.suffix.lower() != ".png":
            fail("--output: learning curves are written as a .png file")
        out = args.output or args.path / "learning_curve.png"
        outputs.check_target(out, force=args.force, flag="--output")  # before anything is read
        path, table = plots.learning_curves(args.path, out, force=args.force)
        print(table, end="")
        print(f"wrote {path}")
        return
    if not args.path.is_file():
        fail(f"{args.path}: no such run directory or replay file")
    from pe_mjx.trajectory import TrajectoryError
    from pe_mjx.trajectory import load as load_trajectory

    try:
        traj = load_trajectory(args.path)
    except TrajectoryError as err:
        fail(str(err))
    out = args.output or args.path.with_suffix(".png")
    outputs.check_target(out, force=args.force, flag="--output")
    if out.suffix.lower() in (".gif", ".mp4"):
        path = plots.animate_trajectory(traj, out, args.arena, args.fps, force=args.force)
    elif out.suffix.lower() == ".png":
        path = plots.plot_trajectory(traj, out, args.arena, force=args.force)
    else:
        fail(f"--output: a replay is plotted to .png, .gif or .mp4, got {out.name}")
    print(f"wrote {path}")
