"""`pe-mjx plot`: learning curves with readable legends, Fig. 4-style trajectory plots, GIFs;
the evaluator's heatmaps and its one compile per policy shape."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from tensorboardX import SummaryWriter

from pe_mjx import eval_games, plots
from pe_mjx.evaluate import evaluate

CLI = str(Path(sys.executable).parent / "pe-mjx")


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([CLI, *args], cwd=cwd, capture_output=True, text=True, timeout=600)


def test_plot_run_learning_curves(tmp_path):
    run = tmp_path / "run"
    writer = SummaryWriter(str(run / "tb"))
    for step in (100, 200, 300):
        writer.add_scalar("eval/pursuer_vs_scripted/success_rate", step / 400, step)
        writer.add_scalar("eval/evader_vs_scripted/success_rate", 1 - step / 400, step)
        writer.add_scalar("eval/pursuer_vs_scripted/pursuer_return", step / 10, step)
    writer.close()
    out = _cli("plot", str(run), cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert (run / "learning_curve.png").stat().st_size > 10_000
    assert "| 200 | 0.500 | 0.500 |" in out.stdout
    assert "learned pursuers vs scripted evaders" in plots.CURVES.values()
    bad = _cli("plot", str(tmp_path / "nothing"), cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.startswith("pe-mjx: error:")


def test_evaluate_compiles_once_per_shape_and_plots_replays(tmp_path):
    eval_games.clear_programs()  # an earlier test of this process may have compiled it
    log: list[str] = []
    report = evaluate(
        ["mix-20-5-8", "mix-20-5-8"], ["scripted"], "2-1-1", tmp_path / "res", trials=2,
        backend="kinematic", record=1, log=log.append,
    )  # fmt: skip
    first, second = report["results"]
    # Same network shape: the second pairing reuses the first one's compiled program.
    assert second.seconds < first.seconds / 3, (first.seconds, second.seconds)
    assert (tmp_path / "res" / "success_rate_heatmap.png").exists()
    replay = tmp_path / "res" / "trajectories" / "pairing-0.npz"
    png = _cli("plot", str(replay), "-o", "fig4.png", cwd=tmp_path)
    assert png.returncode == 0, png.stderr
    gif = _cli("plot", str(replay), "-o", "replay.gif", "--fps", "20", cwd=tmp_path)
    assert gif.returncode == 0, gif.stderr
    assert (tmp_path / "fig4.png").stat().st_size > 10_000
    assert (tmp_path / "replay.gif").read_bytes()[:6] == b"GIF89a"


def test_an_animation_refuses_a_frame_rate_a_gif_cannot_hold(tmp_path):
    """The library checks --fps as the command line does (fps 0 divided by zero; above 100 a
    GIF's delay rounds to 0), before a frame is drawn or a file written."""
    from tests.viewer.viewer_helpers import synthetic_trajectory

    traj = synthetic_trajectory(frames=3)
    for fps in (0, 101, 100_000):
        with pytest.raises(ValueError, match=r"--fps must be in \[1, 100\]"):
            plots.animate_trajectory(traj, tmp_path / "a.gif", fps=fps)
    assert list(tmp_path.iterdir()) == []


def test_a_committed_figure_is_a_palette_png_smaller_than_matplotlibs(tmp_path):
    """docs/figures are written by `plots.save_palette_png`: at most 256 colours, the same bytes
    for the same figure, and smaller than matplotlib's RGBA file of it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from PIL import Image

    fig, ax = plt.subplots(figsize=(6, 4))
    x = np.linspace(0, 3e6, 40)
    for k in range(4):
        ax.plot(x, 1 - np.exp(-x / (5e5 * (k + 1))), marker="o", label=f"seed {k}")
        ax.fill_between(x, 0.9 - np.exp(-x / (4e5 * (k + 1))), 1, alpha=0.2)
    ax.legend()
    first = plots.save_palette_png(fig, tmp_path / "a.png", dpi=100)
    plots.save_palette_png(fig, tmp_path / "b.png", dpi=100)
    fig.savefig(tmp_path / "rgba.png", dpi=100)
    plt.close(fig)
    assert first.read_bytes() == (tmp_path / "b.png").read_bytes()
    with Image.open(first) as image, Image.open(tmp_path / "rgba.png") as rgba:
        assert image.mode == "P" and image.size == rgba.size
        assert len(image.getcolors(256) or []) > 16  # the plot's colours kept, not a few greys
    assert first.stat().st_size < 0.6 * (tmp_path / "rgba.png").stat().st_size
