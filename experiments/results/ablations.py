"""The recipe's ablations as data: each ablated co-evolution against the one it departs from.

    python -m experiments.results.ablations [--out docs/data/ablations]

An ablation is a co-evolution trained with one of the recipe's departures from the paper undone
(`train/runs/<ablated>`: its config, curves and policy), and one `pe-mjx evaluate` under
`docs/data/ablations/<name>` that plays it, the co-evolution it departs from and the scripted
teams against each other (every pursuer against every evader). For each ablation whose
evaluation is committed this writes, to OUT/effects.json and OUT/effects.md, the success rate
and per-evader cost of the pairings that tell the two apart:

* the scripted pursuers against each one's evaders (how hard its evaders are to catch);
* each one's pursuers against the scripted evader;
* each one's pursuers against the other's evaders (the cross-confrontation);
* each one against itself;
* where the spec names a third co-evolution (`also`), each one's pursuers against its evaders and
  its pursuers against each one's evaders (the 1M ablation against the 3M MIX as well as against
  its 1M twin);

and one sentence that `experiments/results/recipe.py` quotes in the deviations table's
"Measured effect" column. One seed each (seed 0), so an effect smaller than the seed spread of
`docs/data/coev-seeds-3m` is not one.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import tyro

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "docs" / "data"
ABLATIONS = {
    "paper_recipe": {
        "what": "undone with the flee shaping, the paper's step size (3e-4, both teams) at 3M",
        "evaluation": "ablations/paper-recipe-3m",
        "ablated": "mix-20-5-8-paper-recipe-3m",
        "ours": "mix-20-5-8-3m",
    },
    "queries_all": {
        "what": "every entity's token queries (full self-attention) at 1M",
        "evaluation": "ablations/queries-all-1m",
        "ablated": "mix-20-5-8-queries-all-1m",
        "ours": "mix-20-5-8",
        "also": "mix-20-5-8-3m",
    },
}


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path = DATA / "ablations"
    """Where effects.json and effects.md go."""


def pairings(results: dict) -> dict[tuple[str, str], dict]:
    """(pursuer, evader) policy names ("scripted", a run's directory name) -> summary."""
    return {
        (Path(p["pursuer"]["source"]).name, Path(p["evader"]["source"]).name): p["summary"]
        for p in results["pairings"]
    }


def effect(spec: dict) -> dict | None:
    """The pairings of one ablation that tell it from ours, or None before it is evaluated."""
    path = DATA / spec["evaluation"] / "results.json"
    if not path.is_file():
        return None
    results = json.loads(path.read_text())
    summaries = pairings(results)
    ablated, ours = spec["ablated"], spec["ours"]
    rows = {
        "scripted_pursuers": ("scripted", ablated, "scripted", ours),
        "scripted_evader": (ablated, "scripted", ours, "scripted"),
        "cross": (ablated, ours, ours, ablated),
        "self": (ablated, ablated, ours, ours),
    }
    also = spec.get("also")
    if also:
        rows["against_also"] = (ablated, also, ours, also)
        rows["also_against"] = (also, ablated, also, ours)
    table = {}
    for name, (p_a, e_a, p_o, e_o) in rows.items():
        a, o = summaries[p_a, e_a], summaries[p_o, e_o]
        table[name] = {
            "ablated": {k: a[k] for k in ("success_rate", "per_evader_cost")},
            "ours": {k: o[k] for k in ("success_rate", "per_evader_cost")},
        }
    rate = {k: {side: f"{v[side]['success_rate']:.3f}" for side in v} for k, v in table.items()}
    cost = {k: f"{v['per_evader_cost']:.3f}" for k, v in table["scripted_evader"].items()}
    text = (
        f"{spec['what']} (`{ablated}` against `{ours}`, `docs/data/{spec['evaluation']}`, "
        f"{results['meta']['trials']} trials): the scripted pursuers catch "
        f"{rate['scripted_pursuers']['ablated']} of its evaders (ours "
        f"{rate['scripted_pursuers']['ours']}); its pursuers catch "
        f"{rate['scripted_evader']['ablated']} of the scripted evader at {cost['ablated']} per "
        f"evader (ours {rate['scripted_evader']['ours']} at {cost['ours']}); across, its pursuers "
        f"catch {rate['cross']['ablated']} of our evaders and ours {rate['cross']['ours']} of its"
    )
    if also:
        text += (
            f"; against `{also}`, its pursuers catch {rate['against_also']['ablated']} of those "
            f"evaders (ours {rate['against_also']['ours']}) and those pursuers "
            f"{rate['also_against']['ablated']} of its evaders (of ours "
            f"{rate['also_against']['ours']})"
        )
    return {**spec, "trials": results["meta"]["trials"], "pairings": table, "text": text}


LABELS = {
    "scripted_pursuers": "the scripted pursuers against its evaders",
    "scripted_evader": "its pursuers against the scripted evader",
    "cross": "its pursuers against the other's evaders",
    "self": "against itself",
    "against_also": "its pursuers against the evaders of `{also}`",
    "also_against": "the pursuers of `{also}` against its evaders",
}


def markdown(effects: dict) -> str:
    lines = [
        "# The recipe's ablations",
        "",
        "Written by `python -m experiments.results.ablations`. Each cell: the ablated "
        "co-evolution's success rate [per-evader cost], then ours.",
        "",
        "| Ablation | Pairing | Ablated | Ours |",
        "|---|---|---|---|",
    ]
    for key, e in effects.items():
        for name, row in e["pairings"].items():
            a, o = row["ablated"], row["ours"]
            lines.append(
                f"| {key} | {LABELS[name].format(also=e.get('also'))} "
                f"| {a['success_rate']:.3f} [{a['per_evader_cost']:.3f}] "
                f"| {o['success_rate']:.3f} [{o['per_evader_cost']:.3f}] |"
            )
    return "\n".join(lines) + "\n"


def main(args: Args) -> None:
    effects = {key: e for key, spec in ABLATIONS.items() if (e := effect(spec)) is not None}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "effects.json").write_text(json.dumps(effects, indent=1) + "\n")
    (args.out / "effects.md").write_text(markdown(effects))
    print(f"wrote {args.out / 'effects.json'} and effects.md ({len(effects)} ablations)")


if __name__ == "__main__":
    main(tyro.cli(Args))
