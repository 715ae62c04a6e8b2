"""Reproduce the paper's Tables II-VI: train co-evolutions, cross-confront, write docs/results.md.

    python tools/reproduce_paper.py --fraction 0.01          # a quick look: 1% of 10M env steps
    python tools/reproduce_paper.py                          # the full 10 million per run
    python tools/reproduce_paper.py --skip-train --runs runs # evaluate existing runs only

Resumable: training resumes every run from its last checkpoint, and a table whose results.json
exists is not evaluated again (delete it to redo it). Tables II-IV: at each scale, every pursuit
policy against every evasion policy of another co-evolution at that scale. Tables V and VI: the
pursuit policies trained at 20-5-8 against the evasion policies trained at 16-4-4 and 24-6-12,
in those scenes (generalization). The paper's numbers stand beside ours.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import sys
from pathlib import Path

import tyro

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "train"))

from paper import ENV_STEPS, paper_runs  # noqa: E402

from pe_mjx.config import ENCODERS  # noqa: E402

# The paper's tables: (evader method, pursuer method) -> (success, travel, pursuit cost,
# per-evader cost).
PAPER = {
    "II": {
        ("mlp", "birnn"): (0.995, 3.948, 4.32, 1.085),
        ("mlp", "mean"): (0.998, 2.954, 3.89, 0.975),
        ("mlp", "mix"): (1.000, 3.527, 4.35, 1.088),
        ("birnn", "mlp"): (0.565, 19.805, 7.05, 3.119),
        ("birnn", "mean"): (0.470, 18.477, 3.71, 1.973),
        ("birnn", "mix"): (0.863, 20.694, 5.18, 1.501),
        ("mean", "mlp"): (0.193, 22.096, 5.32, 6.909),
        ("mean", "birnn"): (0.648, 29.808, 5.26, 2.031),
        ("mean", "mix"): (0.748, 27.832, 4.42, 1.478),
        ("mix", "mlp"): (0.638, 16.641, 8.56, 3.357),
        ("mix", "birnn"): (0.733, 27.303, 5.44, 1.857),
        ("mix", "mean"): (0.503, 19.276, 3.52, 1.751),
    },
    "III": {
        ("mlp", "birnn"): (0.998, 2.743, 6.30, 1.263),
        ("mlp", "mean"): (0.998, 3.068, 5.26, 1.054),
        ("mlp", "mix"): (1.000, 3.637, 4.96, 0.992),
        ("birnn", "mlp"): (0.708, 14.526, 8.34, 2.356),
        ("birnn", "mean"): (1.000, 9.690, 5.68, 1.136),
        ("birnn", "mix"): (0.992, 12.271, 5.38, 1.085),
        ("mean", "mlp"): (0.440, 17.513, 7.31, 3.323),
        ("mean", "birnn"): (0.760, 21.614, 7.61, 2.003),
        ("mean", "mix"): (0.932, 20.138, 5.56, 1.193),
        ("mix", "mlp"): (0.542, 15.306, 9.15, 3.376),
        ("mix", "birnn"): (0.802, 20.432, 9.12, 2.274),
        ("mix", "mean"): (0.932, 21.375, 6.11, 1.311),
    },
    "IV": {
        ("mlp", "birnn"): (0.995, 3.190, 6.72, 1.126),
        ("mlp", "mean"): (1.000, 2.779, 6.16, 1.027),
        ("mlp", "mix"): (1.000, 2.570, 5.93, 0.988),
        ("birnn", "mlp"): (0.867, 6.727, 11.50, 2.211),
        ("birnn", "mean"): (1.000, 5.725, 6.68, 1.113),
        ("birnn", "mix"): (1.000, 4.191, 5.96, 0.993),
        ("mean", "mlp"): (0.378, 7.939, 8.20, 3.616),
        ("mean", "birnn"): (0.943, 14.928, 8.20, 1.449),
        ("mean", "mix"): (1.000, 7.745, 6.49, 1.082),
        ("mix", "mlp"): (0.502, 7.365, 11.05, 3.669),
        ("mix", "birnn"): (0.912, 16.275, 8.59, 1.570),
        ("mix", "mean"): (0.985, 14.509, 8.05, 1.362),
    },
    "V": {
        ("mlp", "birnn"): (0.998, 3.482, 4.86, 1.218),
        ("mlp", "mean"): (1.000, 3.116, 3.94, 0.985),
        ("mlp", "mix"): (1.000, 3.003, 3.74, 0.935),
        ("birnn", "mean"): (0.835, 20.949, 4.39, 1.314),
        ("birnn", "mix"): (0.915, 19.335, 4.04, 1.104),
        ("mean", "birnn"): (0.390, 27.899, 3.59, 2.301),
        ("mean", "mix"): (0.868, 22.598, 3.71, 1.069),
        ("mix", "birnn"): (0.788, 21.943, 6.52, 2.070),
        ("mix", "mean"): (0.893, 22.985, 4.53, 1.269),
    },
    "VI": {
        ("mlp", "birnn"): (0.998, 3.263, 7.92, 1.322),
        ("mlp", "mean"): (1.000, 2.899, 6.24, 1.040),
        ("mlp", "mix"): (0.988, 6.881, 5.79, 0.976),
        ("birnn", "mean"): (1.000, 7.523, 7.08, 1.180),
        ("birnn", "mix"): (0.997, 13.058, 6.36, 1.064),
        ("mean", "birnn"): (0.823, 15.803, 10.83, 2.192),
        ("mean", "mix"): (0.940, 20.449, 6.78, 1.202),
        ("mix", "birnn"): (0.738, 18.743, 11.04, 2.492),
        ("mix", "mean"): (0.900, 20.796, 8.12, 1.504),
    },
}
# Table -> (test scene, scale the pursuers were trained at, scale the evaders were trained at).
TABLES = {
    "II": ("16-4-4", "16-4-4", "16-4-4"),
    "III": ("20-5-8", "20-5-8", "20-5-8"),
    "IV": ("24-6-12", "24-6-12", "24-6-12"),
    "V": ("16-4-4", "20-5-8", "16-4-4"),
    "VI": ("24-6-12", "20-5-8", "24-6-12"),
}


@dataclasses.dataclass(frozen=True)
class Args:
    """Train the paper's co-evolutions and write our Tables II-VI beside the paper's."""

    runs: Path = Path("runs")
    """Where the co-evolution runs live (train/launch.py's layout: <encoder>-<preset>)."""
    out: Path = Path("results/paper")
    """Per-table evaluation outputs."""
    docs: Path = Path("docs/results.md")
    """The report with our tables beside the paper's."""
    fraction: float = 1.0
    """Training budget as a fraction of the paper's 10 million env steps per run."""
    skip_train: bool = False
    """Evaluate the runs that exist; train nothing."""
    encoders: tuple[str, ...] = ENCODERS
    tables: tuple[str, ...] = tuple(TABLES)
    trials: int = 100
    backend: str = "mjx"
    seed: int = 0


def _train(args: Args) -> None:
    from pe_mjx.ppo import checkpoint
    from pe_mjx.ppo.run import train

    budget = max(1, int(ENV_STEPS * args.fraction))
    scales = {scale for table in args.tables for scale in TABLES[table][1:]}
    for name, config in paper_runs(budget, args.backend).items():
        if config.pursuer_encoder not in args.encoders or config.preset not in scales:
            continue  # only the co-evolutions that the chosen tables use
        out = args.runs / name
        resume = (out / checkpoint.CHECKPOINT_DIR).exists()
        if resume and checkpoint.read_meta(out)["env_steps"] >= budget:
            continue
        print(f"training {name} ({budget:,} env steps)", flush=True)
        train(config, out, resume=resume)


def _evaluate(args: Args) -> dict[str, dict]:
    from pe_mjx.evaluate import evaluate
    from pe_mjx.ppo import checkpoint

    done = {}
    for table in args.tables:
        scene, p_scale, e_scale = TABLES[table]
        out = args.out / f"table-{table}"
        if (out / "results.json").exists():
            done[table] = json.loads((out / "results.json").read_text())
            continue

        def have(encoder: str, scale: str) -> bool:
            try:
                checkpoint.read_meta(args.runs / f"{encoder}-{scale}")
                return True
            except checkpoint.CheckpointError:
                return False

        pursuers = [str(args.runs / f"{e}-{p_scale}") for e in args.encoders if have(e, p_scale)]
        evaders = [str(args.runs / f"{e}-{e_scale}") for e in args.encoders if have(e, e_scale)]
        if not pursuers or not evaders:
            print(f"table {table}: no runs for it yet, skipped")
            continue
        print(
            f"table {table}: {len(pursuers)} pursuit x {len(evaders)} evasion policies in {scene}"
        )
        evaluate(
            pursuers,
            evaders,
            scene,
            out,
            args.trials,
            args.seed,
            args.backend,
            record=2,
            skip_same_method=True,
        )
        done[table] = json.loads((out / "results.json").read_text())
    return done


def _report(args: Args, done: dict[str, dict]) -> str:
    lines = [
        "# Paper reproduction: Tables II-VI",
        "",
        f"Written by `tools/reproduce_paper.py` on {datetime.date.today()}; training budget "
        f"{args.fraction:g} x 10M env steps per co-evolution, {args.trials} trials per pairing, "
        f"backend {args.backend}. Each cell: ours / paper. "
        "Per-evader cost is mean(m')/mean(n').",
        "",
    ]
    for table, data in done.items():
        scene, p_scale, e_scale = TABLES[table]
        lines += [
            f"## Table {table}: scene {scene} "
            f"(pursuers trained at {p_scale}, evaders at {e_scale})",
            "",
            "| Evader | Pursuer | Success rate | Travel distance | Pursuit cost "
            "| Per-evader cost |",
            "|---|---|---|---|---|---|",
        ]
        for pairing in data["pairings"]:
            e_method = Path(pairing["evader"]["source"]).name.split("-")[0]
            p_method = Path(pairing["pursuer"]["source"]).name.split("-")[0]
            ours = pairing["summary"]
            ref = PAPER[table].get((e_method, p_method))
            cells = [ours["success_rate"], ours["travel_distance"], ours["pursuit_cost"]]
            cells.append(ours["per_evader_cost"])
            fmt = ("{:.3f}", "{:.2f}", "{:.2f}", "{:.3f}")
            row = [
                f"{f.format(v)} / {'-' if ref is None else f.format(ref[i])}"
                for i, (f, v) in enumerate(zip(fmt, cells, strict=True))
            ]
            lines.append(
                f"| {pairing['evader']['label']} | {pairing['pursuer']['label']} | "
                + " | ".join(row)
                + " |"
            )
        lines.append("")
    if not done:
        lines.append("No table has been evaluated yet.")
    return "\n".join(lines) + "\n"


def main() -> None:
    args = tyro.cli(Args)
    unknown = set(args.tables) - set(TABLES)
    if unknown:
        raise SystemExit(f"unknown tables {sorted(unknown)}; known: {', '.join(TABLES)}")
    if not args.skip_train:
        _train(args)
    done = _evaluate(args)
    args.docs.parent.mkdir(parents=True, exist_ok=True)
    args.docs.write_text(_report(args, done))
    print(f"wrote {args.docs}")


if __name__ == "__main__":
    main()
