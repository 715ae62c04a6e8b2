"""Plots: learning curves from a run's compact curves (or its TensorBoard events), and replays
as a Fig. 4-style top-down trajectory plot or a GIF/MP4 animation (matplotlib, imageio)."""

from __future__ import annotations

import io
import struct
from collections import defaultdict
from pathlib import Path

import numpy as np

from pe_mjx import interrupts, outputs
from pe_mjx.ppo import curves
from pe_mjx.ppo.curves import CURVES_FILE, curves_file
from pe_mjx.trajectory import Trajectory

CURVES = {
    "eval/pursuer_vs_scripted/success_rate": "learned pursuers vs scripted evaders",
    "eval/evader_vs_scripted/success_rate": "scripted pursuers vs learned evaders",
    "episode/success_rate": "co-evolution (training episodes)",
}
"""Success-rate tags (evaders downed / evaders) and their legend labels."""
RETURNS = {
    "eval/pursuer_vs_scripted/pursuer_return": "pursuer return vs scripted evaders",
    "eval/evader_vs_scripted/evader_return": "evader return vs scripted pursuers",
}
"""Per-team episodic-return tags (mean per agent) and their legend labels."""


MAX_EVENTS_BYTES = 256 << 20
"""Largest TensorBoard events file read (a 10M-step run's scalars take tens of MB)."""


def save_palette_png(fig, path: str | Path, dpi: int) -> Path:
    """Writes `fig` to `path` as a PNG of at most 256 colours (median cut, no dithering).

    For the figures the repository commits (docs/figures): a line plot looks the same as
    matplotlib's RGBA file at about a third of its size. The same figure gives the same bytes.
    """
    from PIL import Image

    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=dpi, format="png")
    buffer.seek(0)
    with Image.open(buffer) as image:
        palette = image.convert("RGB").quantize(
            colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
        )
    palette.save(path, format="PNG", optimize=True)
    return Path(path)


def read_scalars(run_dir: str | Path) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(env_steps, value)] of a run: from its compact curves (`curves.csv.xz`), or, for
    a run written before those existed, from its TensorBoard events under `run_dir/tb`.

    Iterations in which no arena finished carry no episode statistics and are dropped from the
    `episode/*` curves.

    Raises:
      CurvesError: the curves file is damaged (one line naming it).
    """
    path = curves_file(run_dir)
    out = curves.scalars(curves.read_rows(path)) if path.exists() else _tensorboard_scalars(run_dir)
    finished = dict(out.get("episode/finished", []))
    for tag in list(out):
        if tag.startswith("episode/") and tag != "episode/finished":
            out[tag] = [(s, v) for s, v in out[tag] if finished.get(s, 1) > 0]
    return out


def _tensorboard_scalars(run_dir: str | Path) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(env_steps, value)] from every event file under `run_dir/tb` (TFRecord framing);
    a record cut by a kill ends the file's reading."""
    from google.protobuf.message import DecodeError
    from tensorboardX.proto import event_pb2

    scalars: dict[str, list[tuple[int, float]]] = defaultdict(list)
    for path in sorted((Path(run_dir) / "tb").glob("events.out.tfevents.*")):
        # Capped: an events file linked to /dev/zero was read until memory ran out (a FIFO
        # reads as empty instead of waiting for a writer).
        data = outputs.read_bytes(path, MAX_EVENTS_BYTES)
        pos = 0
        while pos + 12 <= len(data):
            (length,) = struct.unpack("<Q", data[pos : pos + 8])
            record = data[pos + 12 : pos + 12 + length]
            if len(record) < length:
                break
            try:
                event = event_pb2.Event.FromString(record)
            except DecodeError:
                raise curves.CurvesError(
                    f"{path}: not a TensorBoard event file (a damaged record at byte {pos})"
                ) from None
            pos += 12 + length + 4
            for value in event.summary.value:
                scalars[value.tag].append((event.step, value.simple_value))
    return {k: sorted(v) for k, v in scalars.items()}


def learning_curves(
    run_dir: str | Path, out: str | Path | None = None, force: bool = False
) -> tuple[Path, str]:
    """Writes the run's learning curves (success rates; episodic returns when logged) as a PNG
    (through `pe_mjx.outputs`: an existing file is replaced only with `force`).

    Returns:
      The PNG's path and a Markdown table of the evaluations (env steps, both success rates).
    Raises:
      ValueError: the run has no TensorBoard events.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    scalars = read_scalars(run_dir)
    if not scalars:
        raise ValueError(
            f"{run_dir} holds no learning curves (no {CURVES_FILE}, no tb/events.* files)"
        )
    have_returns = any(tag in scalars for tag in RETURNS)
    fig, axes = plt.subplots(1, 2 if have_returns else 1, figsize=(12 if have_returns else 7, 4))
    axes = np.atleast_1d(axes)
    ax = axes[0]
    for tag, label in CURVES.items():
        if tag in scalars:
            steps, values = zip(*scalars[tag], strict=True)
            ax.plot(steps, values, marker="o" if tag.startswith("eval") else None, label=label)
    ax.set_xlabel("env steps")
    ax.set_ylabel("success rate (evaders downed / evaders)")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, title="pursuer success", title_fontsize=8)
    ax.set_title(f"{run_dir.name}: pursuer success")
    if have_returns:
        for tag, label in RETURNS.items():
            if tag in scalars:
                steps, values = zip(*scalars[tag], strict=True)
                axes[1].plot(steps, values, marker="o", label=label)
        axes[1].set_xlabel("env steps")
        axes[1].set_ylabel("episodic return (mean per agent)")
        axes[1].grid(alpha=0.3)
        axes[1].legend(fontsize=8)
        axes[1].set_title(f"{run_dir.name}: episodic return")
    fig.tight_layout()
    path = Path(out) if out is not None else run_dir / "learning_curve.png"
    try:
        with outputs.writing(path, force=force, flag="--output") as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        plt.close(fig)
    lines = [
        "| env steps | learned pursuers vs scripted evaders "
        "| scripted pursuers vs learned evaders |",
        "|---|---|---|",
    ]
    ev_p = dict(scalars.get("eval/pursuer_vs_scripted/success_rate", []))
    ev_e = dict(scalars.get("eval/evader_vs_scripted/success_rate", []))
    for step in sorted(set(ev_p) | set(ev_e)):
        lines.append(
            f"| {step:,} | {ev_p.get(step, float('nan')):.3f} | "
            f"{ev_e.get(step, float('nan')):.3f} |"
        )
    return path, "\n".join(lines) + "\n"


def _draw_arena(ax, traj: Trajectory, arena: int) -> None:
    import matplotlib.patches as mpatches

    cfg = traj.config
    radius = cfg.arena.radius
    ax.add_patch(mpatches.Circle((0, 0), radius, fill=False, lw=2, color="black"))
    for x, y, r in traj.obstacles[arena]:
        if r > 0:
            ax.add_patch(mpatches.Circle((x, y), r, color="0.55"))
    ax.set_xlim(-radius * 1.05, radius * 1.05)
    ax.set_ylim(-radius * 1.05, radius * 1.05)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def _team_colors(traj: Trajectory) -> list[str]:
    p = traj.config.pursuer.num_agents
    return ["tab:red"] * p + ["tab:blue"] * (traj.poses.shape[2] - p)


def _last_frame(traj: Trajectory, arena: int) -> int:
    """The last frame that differs from its predecessor (recordings repeat the final state)."""
    poses = traj.poses[:, arena]
    moving = np.nonzero(np.any(np.abs(np.diff(poses, axis=0)) > 0, axis=(1, 2)))[0]
    return int(moving[-1]) + 1 if len(moving) else 0


def plot_trajectory(traj: Trajectory, out: str | Path, arena: int = 0, force: bool = False) -> Path:
    """A top-down plot of one recorded arena in the style of the paper's Fig. 4: the wall and
    obstacles, each agent's path (pursuers red, evaders blue) from a hollow start marker, and a
    cross where an agent was downed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not 0 <= arena < traj.num_arenas:
        raise ValueError(f"--arena must be in 0..{traj.num_arenas - 1}, got {arena}")
    end = _last_frame(traj, arena)
    fig, ax = plt.subplots(figsize=(6, 6))
    _draw_arena(ax, traj, arena)
    colors = _team_colors(traj)
    for i, color in enumerate(colors):
        path = traj.poses[: end + 1, arena, i, :2]
        alive = traj.active[: end + 1, arena, i]
        stop = int(np.argmin(alive)) if not alive.all() else end
        ax.plot(path[: stop + 1, 0], path[: stop + 1, 1], color=color, lw=1.2, alpha=0.8)
        ax.plot(*path[0], "o", mfc="none", color=color, ms=6)
        if not alive.all():
            ax.plot(*path[stop], "x", color=color, ms=9, mew=2)
        else:
            ax.plot(*path[-1], "o", color=color, ms=5)
    handles = [
        plt.Line2D([], [], color="tab:red", label="pursuers"),
        plt.Line2D([], [], color="tab:blue", label="evaders"),
        plt.Line2D([], [], ls="", marker="o", mfc="none", color="k", label="start"),
        plt.Line2D([], [], ls="", marker="x", color="k", label="downed"),
    ]
    ax.legend(handles=handles, loc="upper right", fontsize=8)
    who = " vs ".join(str(traj.meta[k]) for k in ("pursuer", "evader") if k in traj.meta)
    ax.set_title(f"{traj.config.name}{': ' + who if who else ''} ({end} steps)", fontsize=10)
    fig.tight_layout()
    out = Path(out)
    try:
        with outputs.writing(out, force=force, flag="--output") as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    finally:
        plt.close(fig)
    return out


MAX_FPS = 100
"""The fastest animation: a GIF counts its frame delays in hundredths of a second, so above 100
fps the delay rounds to 0 and viewers play it at a rate of their own, slower than asked."""


def check_fps(fps: int) -> None:
    """A ValueError naming --fps unless 1 <= `fps` <= `MAX_FPS`."""
    if not 1 <= fps <= MAX_FPS:
        raise ValueError(f"--fps must be in [1, {MAX_FPS}], got {fps}")


def animate_trajectory(
    traj: Trajectory,
    out: str | Path,
    arena: int = 0,
    fps: int = 10,
    stride: int = 1,
    force: bool = False,
) -> Path:
    """A GIF (or MP4 with the `video` extra, imageio-ffmpeg) of one recorded arena, top-down,
    written through `pe_mjx.outputs` (whole or not at all; an existing file only with `force`)."""
    import imageio.v3 as iio
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    check_fps(fps)
    if out.suffix.lower() not in (".gif", ".mp4"):
        raise ValueError(f"an animation is a .gif or .mp4 file, got {out.name}")
    if out.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ValueError(
                "MP4 export needs the video extra: pip install 'pe-mjx[video]' (or write a .gif)"
            ) from None
    if not 0 <= arena < traj.num_arenas:
        raise ValueError(f"--arena must be in 0..{traj.num_arenas - 1}, got {arena}")
    outputs.check_target(out, force=force, flag="--output")  # before the frames are drawn
    end = _last_frame(traj, arena)
    colors = np.array(_team_colors(traj))
    frames = []
    fig, ax = plt.subplots(figsize=(4, 4), dpi=80)
    for t in range(0, end + 1, max(1, stride)):
        interrupts.check()  # a safe point between frames (Ctrl-C)
        ax.clear()
        _draw_arena(ax, traj, arena)
        alive = traj.active[t, arena]
        xy = traj.poses[t, arena, :, :2]
        ax.scatter(xy[alive, 0], xy[alive, 1], c=colors[alive], s=25)
        ax.scatter(xy[~alive, 0], xy[~alive, 1], c=colors[~alive], s=25, marker="x", alpha=0.5)
        ax.set_title(f"{traj.config.name}  step {t}", fontsize=9)
        fig.canvas.draw()
        frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    plt.close(fig)
    with outputs.writing(out, force=force, flag="--output") as tmp:
        if out.suffix.lower() == ".gif":
            iio.imwrite(tmp, np.stack(frames), duration=1000 / fps, loop=0, extension=".gif")
        else:
            iio.imwrite(tmp, np.stack(frames), fps=fps, extension=".mp4")
    return out


__all__ = ["animate_trajectory", "learning_curves", "plot_trajectory", "read_scalars"]
