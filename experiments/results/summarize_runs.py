"""Summarise training runs into one JSON (and Markdown) table: what each changed, how it learned.

    python experiments/results/summarize_runs.py runs/diag/* --reference runs/diag/d1-baseline \
        --out docs/data/evader_diagnosis

For every run directory: the experiment fields that differ from the reference run's config, the
evaluation curve of each learned team against its scripted opponent (TensorBoard
`eval/<team>_vs_scripted/*`), the PPO update size (approx. KL, clip fraction) and the reward
terms per step, each averaged over the first and the last `--window` logged points. Writes
`<out>.json` (the data `docs/results.md` quotes) and `<out>.md`, and copies each run's
`config.json` to `<out>/<run>.json` so that any row reruns with `pe-mjx train --config`.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import tyro

from pe_mjx.plots import read_scalars

EVAL_KEYS = ("length", "success_rate", "evader_distance", "pursuer_distance", "pursuit_cost")


@dataclasses.dataclass(frozen=True)
class Args:
    runs: tyro.conf.Positional[tuple[Path, ...]]
    """Run directories (each with config.json and tb/)."""
    out: Path
    """Output stem: writes <out>.json, <out>.md and <out>/<run>.json."""
    reference: Path | None = None
    """Run directory, or a config.json file, that the others are compared with (default: the
    first run)."""
    window: int = 3
    """Logged points averaged at the start and at the end of each curve."""
    ignore: tuple[str, ...] = ("eval_every", "eval_envs")
    """Config fields left out of the "changed" column (e.g. env.physics_dt, which the kinematic
    backend does not use)."""


def _flat(tree: dict, prefix: str = "") -> dict[str, object]:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _ends(points: list[tuple[int, float]], window: int) -> dict[str, float]:
    values = [v for _, v in points]
    return {
        "first": sum(values[:window]) / len(values[:window]),
        "last": sum(values[-window:]) / len(values[-window:]),
        "first_step": points[0][0],
        "last_step": points[-1][0],
    }


def summarize(run: Path, reference: dict[str, object], window: int) -> dict:
    saved = json.loads((run / "config.json").read_text())
    # Runs made before the experiment config (format 1) saved a flat "train_config".
    config = saved.get("experiment") or {"train_config": saved.get("train_config", {})}
    flat = _flat(config)
    changed = {k: v for k, v in flat.items() if reference.get(k) != v}
    scalars = read_scalars(run)
    curves = {}
    for tag, points in scalars.items():
        parts = tag.split("/")
        keep = tag.startswith("eval/") and parts[-1] in EVAL_KEYS
        keep |= tag.startswith("loss/") and parts[-1] in ("approx_kl", "clip_fraction", "entropy")
        keep |= tag.startswith("reward/evader/")
        if keep and points:
            curves[tag] = _ends(points, window)
    return {"run": run.name, "changed": changed, "curves": curves}


def markdown(rows: list[dict], ignore: tuple[str, ...] = ()) -> str:
    lines = [
        "| run | changed | env steps | eval length (first -> last) | evader travel m | "
        "evader approx. KL |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        c = row["curves"]
        length = c.get("eval/evader_vs_scripted/length")
        travel = c.get("eval/evader_vs_scripted/evader_distance")
        kl = c.get("loss/evader/approx_kl")
        changed = ", ".join(f"{k}={v}" for k, v in row["changed"].items() if k not in ignore)
        steps = f"{length['last_step']:,}" if length else "-"

        def span(x, fmt="{:.1f}"):
            return "-" if x is None else f"{fmt.format(x['first'])} -> {fmt.format(x['last'])}"

        lines.append(
            f"| {row['run']} | {changed or '(reference)'} | {steps} | {span(length)} | "
            f"{span(travel, '{:.2f}')} | {span(kl, '{:.1e}')} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    args = tyro.cli(Args)
    runs = [r for r in args.runs if (r / "config.json").is_file()]
    if not runs:
        raise SystemExit("no run directory with a config.json given")
    ref = args.reference or runs[0]
    ref_file = ref if ref.is_file() else ref / "config.json"
    reference = _flat(json.loads(ref_file.read_text())["experiment"])
    rows = [summarize(run, reference, args.window) for run in runs]
    args.out.mkdir(parents=True, exist_ok=True)
    for run in runs:
        shutil.copyfile(run / "config.json", args.out / f"{run.name}.json")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=2, sort_keys=True) + "\n")
    args.out.with_suffix(".md").write_text(markdown(rows, args.ignore))
    print(markdown(rows, args.ignore))


if __name__ == "__main__":
    main()
