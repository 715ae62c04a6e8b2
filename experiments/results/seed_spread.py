"""Mean and spread over seeds of the same evaluation played with each seed's policies.

    python experiments/results/seed_spread.py docs/data/coev-mix-20-5-8-seeds/s0 .../s1 .../s2 \
        --out docs/data/coev-mix-20-5-8-seeds

Each input is the output directory of one `pe-mjx evaluate` (its results.json), run with one
seed's policies and the same pairings, trials and scene. Pairings are matched by their labels
("P_MIX(20,5,8)" vs "E_scripted"), which the seeds share; only the pairings every evaluation
played are summarised (so a seed's numbers may come from a larger table, such as Table III's
results.json), and the others are listed as left out. Writes `<out>/seeds.json` and
`<out>/seeds.md`: per pairing and metric, every seed's value (itself a mean over that
evaluation's trials, with its 95% interval in the seed's results.md), their mean, the sample
standard deviation over seeds and the range. The spread over seeds is the one that says how much
a result depends on the training run; the per-trial intervals do not.

With `--matrix` (for cross-play tables such as Table III, one `pe-mjx reproduce` per seed), seeds.md
also gets the paper's layout: one matrix per metric in `--matrix`, evaders as rows and pursuers as
columns in the order the labels first appear, each cell "mean ± std [lowest, highest]".
"""

from __future__ import annotations

import dataclasses
import json
import statistics
from pathlib import Path

import tyro

METRICS = {
    "success_rate": ("success", 3),
    "travel_distance": ("pursuer travel m", 2),
    "pursuit_cost": ("pursuit cost", 2),
    "per_evader_cost": ("per-evader cost", 3),
    "length": ("time to capture (steps)", 0),
}


@dataclasses.dataclass(frozen=True)
class Args:
    evaluations: tyro.conf.Positional[tuple[Path, ...]]
    """One `pe-mjx evaluate` output directory per seed, in seed order."""
    out: Path
    """Where seeds.json and seeds.md go."""
    title: str = "Mean and spread over seeds"
    matrix: tuple[str, ...] = ()
    """Metrics (of success_rate, per_evader_cost, ...) also written as evader x pursuer matrices."""


SAME = ("preset", "trials", "seed", "backend")  # what every seed's evaluation must share


def _read(directory: Path) -> tuple[dict, dict[tuple[str, str], dict]]:
    path = directory / "results.json"
    if not path.is_file():
        raise SystemExit(f"seed_spread: error: {path} does not exist (run `pe-mjx evaluate` first)")
    if path.stat().st_size > 64 * 2**20:
        raise SystemExit(f"seed_spread: error: {path} is over 64 MiB; not a results.json")
    try:
        results = json.loads(path.read_text())
        meta = {k: results["meta"][k] for k in SAME}
        pairings = {
            (p["pursuer"]["label"], p["evader"]["label"]): p["summary"] for p in results["pairings"]
        }
    except (ValueError, KeyError, TypeError) as e:
        raise SystemExit(f"seed_spread: error: {path} is not a pe-mjx results.json ({e})") from e
    return meta, pairings


def spread(evaluations: list[dict[tuple[str, str], dict]]) -> tuple[list[dict], list]:
    """Rows for the pairings every evaluation played, and the pairings left out."""
    keys = [k for k in evaluations[0] if all(k in ev for ev in evaluations[1:])]
    if not keys:
        raise SystemExit(
            "seed_spread: error: no pairing (pursuer, evader labels) is in every evaluation"
        )
    left_out = sorted({k for ev in evaluations for k in ev} - set(keys))
    rows = []
    for pursuer, evader in keys:
        row = {"pursuer": pursuer, "evader": evader, "seeds": len(evaluations)}
        for metric in METRICS:
            values = [ev[(pursuer, evader)][metric] for ev in evaluations]
            row[metric] = {
                "values": values,
                "mean": statistics.fmean(values),
                "std": statistics.stdev(values) if len(values) > 1 else 0.0,
                "min": min(values),
                "max": max(values),
            }
        rows.append(row)
    return rows, left_out


def markdown(rows: list[dict], title: str, sources: list[str], left_out: list, meta: dict) -> str:
    lines = [
        f"# {title}",
        "",
        "Written by `python experiments/results/seed_spread.py` from "
        + ", ".join(f"`{s}`" for s in sources)
        + f". Scene {meta['preset']}, {meta['trials']} trials per pairing and seed (trial seed "
        f"{meta['seed']}), {meta['backend']} backend. Each cell: mean over seeds ± sample "
        "standard deviation over seeds [lowest, highest seed].",
        "",
        "| Evader | Pursuer | " + " | ".join(label for label, _ in METRICS.values()) + " |",
        "|---|---|" + "---|" * len(METRICS),
    ]
    for row in rows:
        cells = [_cell(row[metric], digits) for metric, (_, digits) in METRICS.items()]
        lines.append(f"| {row['evader']} | {row['pursuer']} | " + " | ".join(cells) + " |")
    if left_out:
        lines += [
            "",
            "Left out (not played in every evaluation): "
            + "; ".join(f"{e} vs {p}" for p, e in left_out)
            + ".",
        ]
    return "\n".join(lines) + "\n"


def _cell(m: dict, digits: int) -> str:
    mean, std, low, high = (f"{m[k]:.{digits}f}" for k in ("mean", "std", "min", "max"))
    return f"{mean} ± {std} [{low}, {high}]"


def matrices(rows: list[dict], metrics: tuple[str, ...]) -> list[str]:
    """Markdown lines: per metric, a matrix of evaders (rows) by pursuers (columns); a pairing
    that no evaluation shares is "-"."""
    pursuers = list(dict.fromkeys(row["pursuer"] for row in rows))
    evaders = list(dict.fromkeys(row["evader"] for row in rows))
    by_pair = {(row["evader"], row["pursuer"]): row for row in rows}
    lines: list[str] = []
    for metric in metrics:
        label, digits = METRICS[metric]
        lines += [
            "",
            f"{label[0].upper()}{label[1:]}, evaders (rows) against pursuers (columns):",
            "",
            "| Evader \\ Pursuer | " + " | ".join(pursuers) + " |",
            "|---|" + "---|" * len(pursuers),
        ]
        for evader in evaders:
            cells = [
                _cell(by_pair[(evader, p)][metric], digits) if (evader, p) in by_pair else "-"
                for p in pursuers
            ]
            lines.append(f"| {evader} | " + " | ".join(cells) + " |")
    return lines


def main(args: Args) -> None:
    unknown = [m for m in args.matrix if m not in METRICS]
    if unknown:
        raise SystemExit(
            f"seed_spread: error: --matrix: unknown metric {unknown[0]!r}; known: "
            + ", ".join(METRICS)
        )
    if len(args.evaluations) < 2:
        raise SystemExit("seed_spread: error: give at least two evaluations (one per seed)")
    read = [_read(d) for d in args.evaluations]
    for d, (meta, _) in zip(args.evaluations, read, strict=True):
        if meta != read[0][0]:
            raise SystemExit(
                f"seed_spread: error: {d} was evaluated with {meta}, "
                f"{args.evaluations[0]} with {read[0][0]}: not the same evaluation"
            )
    rows, left_out = spread([pairings for _, pairings in read])
    args.out.mkdir(parents=True, exist_ok=True)
    sources = [str(d) for d in args.evaluations]
    (args.out / "seeds.json").write_text(
        json.dumps(
            {
                "evaluations": sources,
                "meta": read[0][0],
                "pairings": rows,
                "left_out": [list(k) for k in left_out],
            },
            indent=1,
        )
        + "\n"
    )
    text = markdown(rows, args.title, sources, left_out, read[0][0])
    if args.matrix:
        text += "\n".join(matrices(rows, args.matrix)) + "\n"
    (args.out / "seeds.md").write_text(text)
    print(f"wrote {args.out / 'seeds.json'} and {args.out / 'seeds.md'}")


if __name__ == "__main__":
    main(tyro.cli(Args))
