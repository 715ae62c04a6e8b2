"""An evaluation's reports: the paper's table layout (results.md), results.csv, trials.csv,
results.json and the heatmaps; and what a results.json read back says of its cost and code."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from pe_mjx.config import EnvConfig
from pe_mjx.eval_metrics import PairingResult

MLP_PADDED_NOTE = (
    "\\* MLP policy run at entity counts other than its training counts: its "
    "input is zero-padded or truncated (SPEC 3.1); it cannot generalise."
)
"""The footnote of a table with a starred (padded) MLP policy in it."""

PAPER_COLUMNS = ("Success Rate", "Travel distance", "Pursuit Cost", "Per-Evader Cost")


def markdown_table(results: list[PairingResult], title: str) -> str:
    """The layout of the paper's Tables II-VI, grouped by evader policy, with 95% intervals."""
    lines = [
        f"### {title}",
        "",
        "| Evader's Policy | Pursuer's Policy | Average Success Rate | Average Travel distance "
        "| Average Pursuit Cost | Average Per-Evader Cost |",
        "|---|---|---|---|---|---|",
    ]
    last = None
    for r in results:
        s = r.summary
        evader = r.evader.label if r.evader.label != last else ""
        last = r.evader.label
        low, high = s["per_evader_cost_ci95"]
        lines.append(
            f"| {evader} | {r.pursuer.label} "
            f"| {s['success_rate']:.3f} ± {s['success_rate_ci95']:.3f} "
            f"| {s['travel_distance']:.3f} ± {s['travel_distance_ci95']:.3f} "
            f"| {s['pursuit_cost']:.2f} ± {s['pursuit_cost_ci95']:.2f} "
            f"| {s['per_evader_cost']:.3f} [{low:.3f}, {high:.3f}] |"
        )
    notes = sorted({r.pursuer.note for r in results} | {r.evader.note for r in results} - {""})
    if "mlp-padded" in notes:
        lines += ["", MLP_PADDED_NOTE]
    return "\n".join(lines) + "\n"


def write_reports(
    results: list[PairingResult], out: Path, env_config: EnvConfig, meta: dict[str, Any]
) -> dict[str, Path]:
    """Writes results.md, results.csv (one row per pairing), trials.csv (one row per trial),
    results.json (everything) and the heatmaps; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    title = (
        f"Results of {env_config.pursuer.num_agents} pursuers, {env_config.evader.num_agents} "
        f"evaders and {env_config.arena.num_obstacles} obstacles"
    )
    paths = {"markdown": out / "results.md"}
    paths["markdown"].write_text(markdown_table(results, title))
    paths["csv"] = out / "results.csv"
    summary_keys = sorted(results[0].summary) if results else []
    with paths["csv"].open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["pairing", "evader", "pursuer", *summary_keys])
        for r in results:
            row = [r.summary[k] for k in summary_keys]
            row = [json.dumps(v) if isinstance(v, list) else v for v in row]
            writer.writerow([r.index, r.evader.label, r.pursuer.label, *row])
    paths["trials"] = out / "trials.csv"
    trial_keys = sorted(results[0].trials) if results else []
    with paths["trials"].open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["pairing", "evader", "pursuer", "trial", *trial_keys])
        for r in results:
            for i in range(len(r.trials[trial_keys[0]])):
                values = [float(r.trials[k][i]) for k in trial_keys]
                writer.writerow([r.index, r.evader.label, r.pursuer.label, i, *values])
    paths["json"] = out / "results.json"
    payload = {
        "meta": meta,
        "env_config": env_config.to_dict(),
        "pairings": [
            {
                "pairing": r.index,
                "pursuer": {
                    "label": r.pursuer.label,
                    "source": r.pursuer.source,
                    "note": r.pursuer.note,
                    "fingerprint": r.pursuer.fingerprint,
                },
                "evader": {
                    "label": r.evader.label,
                    "source": r.evader.source,
                    "note": r.evader.note,
                    "fingerprint": r.evader.fingerprint,
                },
                "summary": r.summary,
                "seconds": r.seconds,
                "kept": r.kept,
                "trials": {k: v.tolist() for k, v in r.trials.items()},
            }
            for r in results
        ],
    }
    paths["json"].write_text(dumps(payload))
    paths.update(plot_heatmaps(results, out, env_config.name, meta.get("trials")))
    return paths


def evaluation_seconds(results: dict[str, Any]) -> float:
    """The wall time of the `pe-mjx evaluate` call that wrote `results` (a results.json read back;
    `meta.seconds`) plus the play time recorded with each pairing it kept from an earlier call
    (whose start-up is not recorded)."""
    kept = sum(p["seconds"] for p in results["pairings"] if p.get("kept"))
    return results["meta"]["seconds"] + kept


def code_provenance(metas: list[dict[str, Any]]) -> dict[str, int]:
    """How many of the results.json `meta`s were written from a clean commit, from a work tree
    with uncommitted changes, or before pe-mjx recorded its code version (`meta.code_version`)."""
    counts = {"clean": 0, "dirty": 0, "not_recorded": 0}
    for meta in metas:
        version = meta.get("code_version")
        counts[
            "not_recorded" if version is None else "dirty" if version["git_dirty"] else "clean"
        ] += 1
    return counts


def provenance_text(counts: dict[str, int]) -> str:
    """`code_provenance`'s counts in words: "clean commit", or "1 of 4 clean commit, 3 of 4
    dirty tree"."""
    total = sum(counts.values())
    if counts["clean"] == total:
        return "clean commit"
    words = {"clean": "clean commit", "dirty": "dirty tree", "not_recorded": "not recorded"}
    return ", ".join(f"{n} of {total} {words[k]}" for k, n in counts.items() if n)


_NUMBERS = re.compile(r"\[\s*([-+0-9.eE,\s]|NaN|Infinity)*\s*\]")


_INTEGRAL = re.compile(r"(-?[0-9]+)\.0")


def dumps(payload: Any) -> str:
    """`payload` as indented JSON with each list of numbers on one line (the per-trial values:
    one number a line made the committed results files twice their size), a whole number in
    such a list without its ".0" (counts, lengths and most rates: a quarter of the size). JSON
    readers give an int back where the float was whole: the same number."""

    def number(text: str) -> str:
        text = text.strip()
        whole = _INTEGRAL.fullmatch(text)
        return whole.group(1) if whole else text

    def one_line(match: re.Match) -> str:
        return "[" + ", ".join(number(x) for x in match.group(0)[1:-1].split(",")) + "]"

    return _NUMBERS.sub(one_line, json.dumps(payload, indent=1))


def plot_heatmaps(
    results: list[PairingResult], out: Path, preset: str = "", trials: int | None = None
) -> dict[str, Path]:
    """Success rate and per-evader cost as heatmaps over pursuer x evader policies, titled with
    the preset and the trials per pairing; each cell's number is black or white by the
    luminance of its colour, so it reads on every cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p_labels = list(dict.fromkeys(r.pursuer.label for r in results))
    e_labels = list(dict.fromkeys(r.evader.label for r in results))
    paths = {}
    for key, name, cmap in (
        ("success_rate", "Success rate", "viridis"),
        ("per_evader_cost", "Per-evader cost", "magma_r"),
    ):
        grid = np.full((len(e_labels), len(p_labels)), np.nan)
        for r in results:
            grid[e_labels.index(r.evader.label), p_labels.index(r.pursuer.label)] = r.summary[key]
        fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(p_labels), 1.2 + 0.8 * len(e_labels)))
        finite = np.where(np.isfinite(grid), grid, np.nan)
        im = ax.imshow(finite, cmap=cmap, aspect="auto")
        ax.set_xticks(range(len(p_labels)), p_labels, rotation=30, ha="right")
        ax.set_yticks(range(len(e_labels)), e_labels)
        ax.set_xlabel("pursuer policy")
        ax.set_ylabel("evader policy")
        for (i, j), v in np.ndenumerate(grid):
            if np.isnan(v):
                continue
            # An inf cell is left blank (NaN in the image): white under its text.
            r, g, b, _ = im.cmap(im.norm(v)) if np.isfinite(v) else (1.0, 1.0, 1.0, 1.0)
            luminance = 0.2126 * r + 0.7152 * g + 0.0722 * b
            ax.text(
                j,
                i,
                "inf" if np.isinf(v) else f"{v:.2f}",
                ha="center",
                va="center",
                color="black" if luminance > 0.5 else "white",
                fontsize=9,
            )
        fig.colorbar(im, ax=ax, label=name)
        details = [f"preset {preset}" if preset else "", f"{trials} trials" if trials else ""]
        details = [d for d in details if d]
        ax.set_title(f"{name} ({', '.join(details)})" if details else name)
        fig.tight_layout()
        path = out / f"{key}_heatmap.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        paths[f"{key}_heatmap"] = path
    return paths
