"""Table III at the paper's budget: ours at 10M env steps beside ours at 3M and the paper's.

    python -m experiments.results.budget

Reads the two `pe-mjx reproduce` outputs of Table III (`docs/data/paper-10m`: the co-evolutions
trained to 10M env steps on MJX; `docs/data/paper-3m`: the 3M ones, kinematic) and the paper's
Table III (`pe_mjx.paper.PAPER`), and writes `docs/data/paper-10m/budget.md`: two matrices,
evaders as rows and pursuers as columns (the scripted teams included), one of success and one of
per-evader cost, each cell "10M (3M; paper)". Only methods with a 10M policy appear. It also
draws `docs/figures/curves-20-5-8-10m.png` from the committed curves of the 10M runs
(`train/runs/<method>-20-5-8-10m/curves.csv.xz`), with their 3M seed-0 runs
(`train/runs/<method>-20-5-8-s0`) dashed: each learned team against the scripted opponent.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import tyro

from pe_mjx.names import ENCODERS
from pe_mjx.paper import PAPER
from pe_mjx.plots import save_palette_png
from pe_mjx.ppo.curves import CURVES_FILE, read_rows, scalars

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "docs" / "data"
RUNS = ROOT / "train" / "runs"
ORDER = ("mix", "mean", "birnn", "mlp", "scripted")
COLOURS = {"mix": "tab:red", "mean": "tab:blue", "birnn": "tab:green", "mlp": "tab:purple"}
PANELS = {
    "eval/pursuer_vs_scripted/success_rate": "learned pursuers vs the scripted evader: success",
    "eval/evader_vs_scripted/success_rate": "the scripted pursuers vs learned evaders: success",
    "eval/evader_vs_scripted/length": "the scripted pursuers vs learned evaders: length (steps)",
}


@dataclasses.dataclass(frozen=True)
class Args:
    ten: Path = DATA / "paper-10m" / "table-III" / "results.json"
    """Table III at 10M (`pe-mjx reproduce ... --suffix -10m`)."""
    three: Path = DATA / "paper-3m" / "table-III" / "results.json"
    """Table III at 3M."""
    out: Path = DATA / "paper-10m" / "budget.md"
    figure: Path = ROOT / "docs" / "figures" / "curves-20-5-8-10m.png"
    runs: Path = RUNS
    """Where the runs' `<method>-20-5-8-10m` and `<method>-20-5-8-s0` curves are."""


def method(label: str) -> str:
    """The method of a label: P_MIX(20,5,8) -> mix, E_scripted -> scripted."""
    return re.match(r"[PE]_([A-Za-z]+)", label).group(1).lower()


def cells(path: Path) -> dict[tuple[str, str], dict]:
    """(evader method, pursuer method) -> the pairing's summary, from a results.json."""
    if not path.is_file():
        raise SystemExit(f"budget: error: {path} does not exist (run `pe-mjx reproduce` first)")
    try:
        pairings = json.loads(path.read_text())["pairings"]
        return {
            (method(p["evader"]["label"]), method(p["pursuer"]["label"])): p["summary"]
            for p in pairings
        }
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise SystemExit(f"budget: error: {path} is not a pe-mjx results.json ({e})") from None


def _matrix(ten: dict, three: dict, cell) -> list[str]:
    methods = [m for m in ORDER if any(m in pair for pair in ten)]
    head = "| Evader \\ Pursuer | " + " | ".join(_label("P", m) for m in methods) + " |"
    rows = [head, "|---" * (len(methods) + 1) + "|"]
    for evader in methods:
        row = [cell(ten.get((evader, p)), three.get((evader, p)), evader, p) for p in methods]
        rows.append(f"| {_label('E', evader)} | " + " | ".join(row) + " |")
    return rows


def _label(team: str, m: str) -> str:
    return f"{team}_{m if m == 'scripted' else m.upper()}"


def _paper(evader: str, pursuer: str, column: int) -> str:
    value = PAPER["III"].get((evader, pursuer))
    return "-" if value is None else f"{value[column]:.3f}"


def _success(ten, three, evader, pursuer) -> str:
    if ten is None:
        return "not played"
    before = "-" if three is None else f"{three['success_rate']:.3f}"
    return (
        f"{ten['success_rate']:.3f} ± {ten['success_rate_ci95']:.3f} "
        f"({before}; {_paper(evader, pursuer, 0)})"
    )


def _cost(ten, three, evader, pursuer) -> str:
    if ten is None:
        return "not played"
    before = "-" if three is None else f"{three['per_evader_cost']:.3f}"
    return f"{ten['per_evader_cost']:.3f} ({before}; {_paper(evader, pursuer, 3)})"


def render(ten: dict, three: dict) -> str:
    """The report: the success matrix, then the per-evader cost matrix."""
    return "\n".join(
        [
            "# Table III at 10M env steps beside 3M and the paper",
            "",
            "Written by `python -m experiments.results.budget`. Rows: evaders; columns: pursuers.",
            "Each cell: ours at 10M (ours at 3M; the paper's, '-' where it has no such cell).",
            "",
            "Success rate (10M ± its 95% interval):",
            "",
            *_matrix(ten, three, _success),
            "",
            "Per-evader cost, mean(m') / mean(n'):",
            "",
            *_matrix(ten, three, _cost),
            "",
        ]
    )


def curves(runs: Path, name: str) -> dict[str, list[tuple[int, float]]]:
    path = runs / name / CURVES_FILE
    return scalars(read_rows(path)) if path.is_file() else {}


def draw(runs: Path, figure: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(PANELS), figsize=(6 * len(PANELS), 4))
    for encoder in ENCODERS:
        for suffix, style in (("10m", "-"), ("s0", "--")):
            series = curves(runs, f"{encoder}-20-5-8-{suffix}")
            for ax, tag in zip(axes, PANELS, strict=True):
                if series.get(tag):
                    steps, values = zip(*series[tag], strict=True)
                    label = f"{encoder.upper()} {'10M' if suffix == '10m' else '3M'}"
                    ax.plot(steps, values, style, color=COLOURS[encoder], label=label, lw=1.2)
    for ax, title in zip(axes, PANELS.values(), strict=True):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    for ax in axes[:2]:
        ax.set_ylim(0, 1.02)
    fig.suptitle("20-5-8 co-evolutions to 10M env steps (solid) and 3M (dashed), seed 0")
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    figure.parent.mkdir(parents=True, exist_ok=True)
    save_palette_png(fig, figure, dpi=90)
    plt.close(fig)
    return figure


def main(args: Args) -> None:
    args.out.write_text(render(cells(args.ten), cells(args.three)))
    print(f"wrote {args.out}")
    print(f"wrote {draw(args.runs, args.figure)}")


if __name__ == "__main__":
    main(tyro.cli(Args))
