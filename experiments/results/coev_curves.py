"""Learning curves of the co-evolutions, one figure per run, from data kept in the repo.

    python experiments/results/coev_curves.py --runs runs/coev/mlp-20-5-8-s0 ...
    python experiments/results/coev_curves.py   # redraw from docs/data/coev_curves.json

With --runs, the evaluation curves of each run (its TensorBoard events: every `--eval-every`
iterations each learned team plays against the scripted opponent) and the training episodes'
success rate are written to docs/data/coev_curves.json; the figures (docs/figures/curves-RUN.png)
are always drawn from that file, so they can be redrawn without the runs. Runs that differ only in
their seed suffix (`mix-20-5-8-s0`, `-s1`, `-s2`) also get one figure together,
docs/figures/curves-mix-20-5-8-seeds.png: the mean over seeds of each evaluation curve at the
env steps every seed was evaluated at, with the range over seeds shaded.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import tyro

from pe_mjx.plots import save_palette_png

ROOT = Path(__file__).resolve().parents[2]
# tag -> (panel, legend label, colour: blue = the learned pursuers, orange = the learned evaders)
SERIES = {
    "eval/pursuer_vs_scripted/success_rate": (
        "success",
        "learned pursuers vs scripted evaders",
        "tab:blue",
    ),
    "eval/evader_vs_scripted/success_rate": (
        "success",
        "scripted pursuers vs learned evaders",
        "tab:orange",
    ),
    "episode/success_rate": ("success", "training episodes (the run's own two teams)", "tab:green"),
    "eval/pursuer_vs_scripted/length": (
        "length",
        "learned pursuers vs scripted evaders",
        "tab:blue",
    ),
    "eval/evader_vs_scripted/length": (
        "length",
        "scripted pursuers vs learned evaders",
        "tab:orange",
    ),
    "eval/pursuer_vs_scripted/pursuer_teammate": (
        "teammates",
        "learned pursuers vs scripted evaders",
        "tab:blue",
    ),
    "episode/pursuer_teammate": (
        "teammates",
        "training episodes (the run's own two teams)",
        "tab:green",
    ),
}
PANELS = {
    "success": "pursuer success rate (evaders captured / evaders)",
    "length": "episode length (steps; longer = evaders last longer)",
    "teammates": "pursuers lost to teammates per episode",
}
OPTIONAL = ("teammates",)
"""Panels drawn only for runs whose data has them (collected after they were added)."""
EVERY = 10  # keep every 10th point of the per-iteration training series (the file stays small)


@dataclasses.dataclass(frozen=True)
class Args:
    runs: tuple[Path, ...] = ()
    """Run directories to read (default: redraw from the data file)."""
    data: Path = ROOT / "docs" / "data" / "coev_curves.json"
    figures: Path = ROOT / "docs" / "figures"


def collect(runs: tuple[Path, ...]) -> dict[str, dict[str, list[list[float]]]]:
    from pe_mjx.plots import read_scalars

    out = {}
    for run in runs:
        scalars = read_scalars(run)
        if not scalars:
            raise SystemExit(f"coev_curves: error: {run} holds no TensorBoard events")
        series = {}
        for tag in SERIES:
            points = sorted(dict(scalars.get(tag, [])).items())
            if not tag.startswith("eval/"):
                points = points[::EVERY]
            series[tag] = [[int(s), float(v)] for s, v in points]
        out[run.name] = series
    return out


def draw(data: dict, figures: Path) -> list[Path]:
    plt = _pyplot()

    figures.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, series in data.items():
        panels = {p: y for p, y in PANELS.items() if p not in OPTIONAL or _has(series, p)}
        fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4))
        for ax, (panel, ylabel) in zip(axes, panels.items(), strict=True):
            for tag, (where, label, color) in SERIES.items():
                points = series.get(tag, [])
                if where != panel or not points:
                    continue
                steps, values = zip(*points, strict=True)
                marker = "o" if tag.startswith("eval/") else None
                ax.plot(steps, values, marker=marker, markersize=3, label=label, color=color)
            _style(ax, panel, ylabel)
        title = f"{name}: each learned team against the scripted opponent"
        paths.append(_save(fig, title, figures / f"curves-{name}.png"))
    return paths


def _has(series: dict, panel: str) -> bool:
    return any(series.get(tag) for tag, (where, _, _) in SERIES.items() if where == panel)


def _style(ax, panel: str, ylabel: str) -> None:
    ax.set_xlabel("env steps")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    if panel == "success":
        ax.set_ylim(0, 1.02)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    return plt


def _save(fig, title: str, path: Path) -> Path:
    plt = _pyplot()
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    save_palette_png(fig, path, dpi=100)
    plt.close(fig)
    return path


def seed_groups(data: dict) -> dict[str, list[str]]:
    """Run names grouped by everything but their seed suffix, for groups of two or more."""
    groups: dict[str, list[str]] = {}
    for name in data:
        groups.setdefault(re.sub(r"-s\d+$", "", name), []).append(name)
    return {g: sorted(names) for g, names in groups.items() if len(names) > 1}


def draw_seeds(data: dict, figures: Path) -> list[Path]:
    import numpy as np

    plt = _pyplot()

    paths = []
    for group, names in seed_groups(data).items():
        panels = {p: y for p, y in PANELS.items() if p not in OPTIONAL}
        fig, axes = plt.subplots(1, len(panels), figsize=(12, 4))
        for ax, (panel, ylabel) in zip(axes, panels.items(), strict=True):
            for tag, (where, label, color) in SERIES.items():
                if where != panel or not tag.startswith("eval/"):
                    continue
                curves = [dict(map(tuple, data[n].get(tag, []))) for n in names]
                steps = sorted(set.intersection(*(set(c) for c in curves)))
                if not steps:
                    continue
                values = np.array([[c[s] for s in steps] for c in curves])
                ax.plot(
                    steps,
                    values.mean(0),
                    marker="o",
                    markersize=3,
                    color=color,
                    label=f"{label} (mean of {len(names)} seeds)",
                )
                ax.fill_between(
                    steps,
                    values.min(0),
                    values.max(0),
                    color=color,
                    alpha=0.2,
                    label=f"{label} (range over seeds)",
                )
            _style(ax, panel, ylabel)
        seeds = ", ".join(n.rsplit("-s", 1)[1] for n in names)
        title = f"{group}, seeds {seeds}: each learned team against the scripted opponent"
        paths.append(_save(fig, title, figures / f"curves-{group}-seeds.png"))
    return paths


def main(args: Args) -> None:
    if args.runs:
        data = json.loads(args.data.read_text()) if args.data.exists() else {}
        data.update(collect(args.runs))
        args.data.parent.mkdir(parents=True, exist_ok=True)
        args.data.write_text(json.dumps(data, indent=1) + "\n")
        print(f"wrote {args.data}")
    elif not args.data.exists():
        raise SystemExit(f"coev_curves: error: {args.data} does not exist; give --runs")
    data = json.loads(args.data.read_text())
    for path in draw(data, args.figures) + draw_seeds(data, args.figures):
        print(f"wrote {path}")


if __name__ == "__main__":
    main(tyro.cli(Args))
