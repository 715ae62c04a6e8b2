"""Summaries of the cross-confrontation tables that the paper's findings are judged on.

    python experiments/results/paper_findings.py [--data docs/data/paper]

Reads `<data>/table-*/results.json` (written by `pe-mjx reproduce`) and writes
`<data>/findings.json` and `<data>/findings.md`: per table, each learned pursuit method's mean
success and per-evader cost over the other co-evolutions' evaders it met (the paper's cross
pairings; scripted and same-method pairings are left out) and each evasion method's mean success
conceded over the other co-evolutions' pursuers (lower is better for the evaders). Means over
pairings, each pairing 100 trials: a pairing is one number here, so no interval is given; the
per-pairing intervals are in each table's results.md.

Those evader means are over different opponents (MIX's evaders never meet MIX's pursuers), so for
each two evasion methods A and B it also gives their "duel": each one's mean success conceded
over the same pursuers, the learned methods other than A and B that met both. The paper's
finding that MIX evaders dominate MEAN as the scale grows is judged on it, table by table.
"""

from __future__ import annotations

import dataclasses
import json
from collections import defaultdict
from pathlib import Path

import tyro

from pe_mjx.names import ENCODERS
from pe_mjx.reproduce import method_of

ROOT = Path(__file__).resolve().parents[2]


@dataclasses.dataclass(frozen=True)
class Args:
    data: Path = ROOT / "docs" / "data" / "paper"
    """The reproduce output (table-II ... table-VI)."""


def _learned_pairings(results: dict):
    """(pursuit method, evasion method, summary) of each pairing of two learned policies."""
    for pairing in results["pairings"]:
        p, e = method_of(pairing["pursuer"]["source"]), method_of(pairing["evader"]["source"])
        if p in ENCODERS and e in ENCODERS:
            yield p, e, pairing["summary"]


def summarize(results: dict) -> dict:
    by_p, by_e = defaultdict(list), defaultdict(list)
    for p, e, s in _learned_pairings(results):
        row = {
            "success": s["success_rate"],
            "per_evader_cost": s["per_evader_cost"],
            "travel": s["travel_distance"],
            "against": e,
        }
        if p != e:  # the paper's cross pairings only
            by_p[p].append(row)
            by_e[e].append({**row, "against": p})

    def mean(rows: list[dict], key: str) -> float:
        return sum(r[key] for r in rows) / len(rows)

    return {
        "pursuers": {
            m: {
                "success": mean(rows, "success"),
                "per_evader_cost": mean(rows, "per_evader_cost"),
                "travel": mean(rows, "travel"),
                "against": [r["against"] for r in rows],
            }
            for m, rows in sorted(by_p.items())
        },
        "evaders": {
            m: {
                "success_conceded": mean(rows, "success"),
                "travel_forced": mean(rows, "travel"),
                "against": [r["against"] for r in rows],
            }
            for m, rows in sorted(by_e.items())
        },
    }


def duels(results: dict) -> dict[str, dict]:
    """For each two evasion methods: their mean success conceded over the common pursuers."""
    conceded: dict[str, dict[str, float]] = defaultdict(dict)
    for p, e, s in _learned_pairings(results):
        conceded[e][p] = s["success_rate"]
    out = {}
    methods = [m for m in ENCODERS if m in conceded]
    for i, a in enumerate(methods):
        for b in methods[i + 1 :]:
            common = [
                p for p in ENCODERS if p not in (a, b) and p in conceded[a] and p in conceded[b]
            ]
            if common:
                out[f"{a}-{b}"] = {
                    "against": common,
                    a: sum(conceded[a][p] for p in common) / len(common),
                    b: sum(conceded[b][p] for p in common) / len(common),
                }
    return out


def main(args: Args) -> None:
    tables = sorted(args.data.glob("table-*/results.json"))
    if not tables:
        raise SystemExit(f"paper_findings: error: no table-*/results.json under {args.data}")
    out = {}
    for path in tables:
        results = json.loads(path.read_text())
        out[path.parent.name] = {**summarize(results), "duels": duels(results)}
    (args.data / "findings.json").write_text(json.dumps(out, indent=1) + "\n")
    lines = [
        "# Per-method means over each table's cross pairings",
        "",
        "Written by `python experiments/results/paper_findings.py` from `table-*/results.json`. "
        "A method's "
        "mean is over the pairings with the other methods (scripted and same-method pairings "
        "left out); lower success conceded is a stronger evader.",
        "",
    ]
    for name, summary in out.items():
        lines += [
            f"## {name}",
            "",
            "| pursuit method | mean success | mean per-evader cost | mean travel m | against |",
            "|---|---|---|---|---|",
        ]
        for m, r in summary["pursuers"].items():
            lines.append(
                f"| {m} | {r['success']:.3f} | {r['per_evader_cost']:.3f} | {r['travel']:.2f} "
                f"| {', '.join(r['against'])} |"
            )
        lines += [
            "",
            "| evasion method | mean success conceded | mean travel forced m | against |",
            "|---|---|---|---|",
        ]
        for m, r in summary["evaders"].items():
            lines.append(
                f"| {m} | {r['success_conceded']:.3f} | {r['travel_forced']:.2f} "
                f"| {', '.join(r['against'])} |"
            )
        lines += [
            "",
            "| evasion methods A vs B | A: success conceded | B: success conceded "
            "| over the pursuers of |",
            "|---|---|---|---|",
        ]
        for pair, r in summary["duels"].items():
            a, b = pair.split("-")
            lines.append(f"| {a} vs {b} | {r[a]:.3f} | {r[b]:.3f} | {', '.join(r['against'])} |")
        lines.append("")
    (args.data / "findings.md").write_text("\n".join(lines))
    print(f"wrote {args.data / 'findings.json'} and {args.data / 'findings.md'}")


if __name__ == "__main__":
    main(tyro.cli(Args))
