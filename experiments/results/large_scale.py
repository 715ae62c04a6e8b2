"""Beyond the paper: a policy trained at 20-5-8 played at 10x the paper's largest scale.

    python experiments/results/large_scale.py [--trials 10] [--out docs/data/large-scale]

Plays the shipped local-attention MIX policy (`mix-20-5-8-3m-k4`: the 3M MIX co-evolution's
parameters, each team reading only the 4 nearest entities of each type) and the scripted teams
against each other in four scenes at the paper's density: 20-5-8 (where it was trained),
60-15-30 and 120-30-60 (held out) and 240-60-120; and, at 240-60-120, the ablation over k (the
same parameters with k = 1, 2, 8, 16, full attention being docs/data/transfer-240-60-120-3m; and
the MEAN and BIRNN co-evolutions' pursuers with k = 4); and in every scene the evaders of the
same policy fine-tuned at 60-15-30 (`e-mix-k4-ft-60-15-30`) and then at 240-60-120
(`e-mix-k4-ft-240-60-120`) against the local and the scripted pursuers; and in every scene the
pursuers fine-tuned at 240-60-120 against that evader (`p-mix-k4-ft-240-60-120`), and those
fine-tuned again at 20-5-8 (train/runs/p-mix-k4-ft8-20-5-8), against every evader above;
and at 240-60-120, k = 1 and 2 against the evader fine-tuned there; and in every scene, against
every evader above, the local pursuers reading the distances to their neighbours in units of
5 m (`NetworkConfig.length_unit`, no training) and those fine-tuned at 240-60-120
(`p-mix-k4-5m-ft-240-60-120`); and at 240-60-120, every pursuer fine-tuned there, the local and
the scripted pursuers against the evader fine-tuned in turn against the last
(train/runs/e-mix-k4-ft2-240-60-120).
Each (scene, part) is one `pe-mjx evaluate` report under OUT/<scene>/<part>/; OUT/summary.json
and OUT/summary.md gather the headline numbers that docs/results.md quotes: those of every scene
with reports under OUT, whichever `--scenes` played, each row with its part, and each part with
the code version that played it (`provenance`: the page quotes only parts played from a clean
commit). A part whose results.json exists is kept (delete it to play it again), so an
interrupted run continues where it stopped.

The held-out scenes keep 24-6-12's density (area per entity), as the 240-60-120 preset does:
arena radius 5 m x sqrt(entities / 42).
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
from pathlib import Path

import tyro

from pe_mjx.config import scene_by_counts
from pe_mjx.evaluate import evaluate
from pe_mjx.policy.ship import ship_policy

ROOT = Path(__file__).resolve().parents[2]
LOCAL = "mix-20-5-8-3m-k4"
"""The shipped local-attention policy (pe-mjx ship mix-20-5-8-3m ... --nearest-k 4)."""
FULL = "mix-20-5-8-3m"
"""The same parameters with full attention (the Table III policy)."""
TUNED_EVADERS = {
    "tuned-evader": "e-mix-k4-ft-60-15-30",
    "tuned-evader-240": "e-mix-k4-ft-240-60-120",
}
"""Part -> LOCAL's evaders fine-tuned against LOCAL's frozen pursuers (`--evader.init`; model
cards in assets/policies/README.md): at 60-15-30, then that one again at 240-60-120."""
TUNED_PURSUERS = {
    "tuned-pursuer": "p-mix-k4-ft-240-60-120",
    "tuned-pursuer-then-20-5-8": str(ROOT / "train" / "runs" / "p-mix-k4-ft8-20-5-8"),
    "tuned-pursuer-5m": "p-mix-k4-5m-ft-240-60-120",
}
"""Part -> LOCAL's pursuers fine-tuned at 240-60-120 against the frozen `e-mix-k4-ft-240-60-120`
with the pursuit shaping summed over the 4 nearest evaders (`reward.pursuit_nearest = 4`); and
those fine-tuned again, at 20-5-8 against the frozen full-attention E_MIX (a finished run's
directory: its policy); and METRES's pursuers (neighbour distances in units of 5 m) fine-tuned at
240-60-120 the same way as the first."""
ABLATION = (
    (FULL, 1),
    (FULL, 2),
    (FULL, 8),
    (FULL, 16),
    ("mean-20-5-8-3m", 4),
    ("birnn-20-5-8-3m", 4),
)
"""(policy, k) pairs of the ablation at the largest scene: k for MIX, and MEAN's pooling and
BIRNN's recurrence made local with the same k as the shipped MIX."""
NEXT_EVADER = str(ROOT / "train" / "runs" / "e-mix-k4-ft2-240-60-120")
"""`e-mix-k4-ft-240-60-120` fine-tuned once more at 240-60-120, against the frozen
`p-mix-k4-5m-ft-240-60-120` (a finished run's directory: its policy); played there only."""
METRES = (FULL, 4, 5.0)
"""LOCAL reading the distances to its neighbours in units of 5 m, 20-5-8's arena radius, in
every arena (`NetworkConfig.length_unit`; pe-mjx ship --nearest-k 4 --length-unit 5):
the same play as LOCAL at 20-5-8, and a neighbourhood of the same density read the same way at
every other scale. No training."""


@dataclasses.dataclass(frozen=True)
class Args:
    trials: int = 10
    """Episodes per pairing in the scenes above 20-5-8 (20-5-8 plays 100)."""
    out: Path = ROOT / "docs" / "data" / "large-scale"
    """Where the reports and the summary go."""
    backend: str = "kinematic"
    """Env backend of every trial."""
    scenes: tuple[str, ...] = ("20-5-8", "60-15-30", "120-30-60", "240-60-120")
    """Scenes to play (names P-E-K)."""


def play(args: Args) -> dict:
    summary: dict = {"trials": {}, "scenes": {}, "provenance": {}}
    with tempfile.TemporaryDirectory() as tmp:
        variants = {}  # path of the local copy -> its name
        for source, k, unit in [*((source, k, None) for source, k in ABLATION), METRES]:
            name = f"{source}-k{k}" + ("" if unit is None else f"-{unit:g}m")
            ship_policy(
                ROOT / "assets" / "policies" / source,
                name,
                dest=Path(tmp),
                nearest_k=k,
                length_unit=unit,
            )
            variants[str(Path(tmp) / name)] = name
        *ablation_paths, metres = variants  # METRES last
        ablation = {p: variants[p] for p in ablation_paths}
        # Every scene with reports is summarised; only those of --scenes are played.
        scenes = list(dict.fromkeys([*Args.scenes, *args.scenes]))
        for name in scenes:
            env_config = scene_by_counts(name)
            trials = 100 if name == "20-5-8" else args.trials
            parts = {
                "main": ([LOCAL, "scripted"], [LOCAL, FULL, "scripted"]),
            }
            for part, tuned in TUNED_EVADERS.items():
                parts[part] = ([LOCAL, "scripted"], [tuned])
            every_evader = [LOCAL, FULL, "scripted", *TUNED_EVADERS.values()]
            parts["metres"] = ([metres], every_evader)
            for part, tuned in TUNED_PURSUERS.items():
                parts[part] = ([tuned], every_evader)
            if name == scenes[-1]:
                # Full attention at 240-60-120 takes about 95 s per trial on 2 CPU cores: its
                # row is docs/data/transfer-240-60-120-3m (5 trials), quoted beside these.
                mix_k = [p for p, n in ablation.items() if n.startswith(FULL)]
                parts["ablation"] = (mix_k, ["scripted"])
                # Smaller k against the evader fine-tuned against k = 4 (same parameters).
                small_k = [p for p in mix_k if variants[p] in (f"{FULL}-k1", f"{FULL}-k2")]
                parts["ablation-vs-tuned-evader"] = (small_k, [TUNED_EVADERS["tuned-evader-240"]])
                parts["next-evader"] = (
                    [*TUNED_PURSUERS.values(), LOCAL, "scripted"],
                    [NEXT_EVADER],
                )
                for path, variant in ablation.items():  # one part per other encoder
                    if path not in mix_k:
                        parts[f"ablation-{variant.split('-')[0]}"] = ([path], ["scripted"])
            for part, (pursuers, evaders) in parts.items():
                out = args.out / name / part
                if not (out / "results.json").is_file():
                    if name not in args.scenes:
                        continue
                    evaluate(
                        pursuers,
                        evaders,
                        env_config,
                        out,
                        trials=trials,
                        backend=args.backend,
                        record=0,
                    )
                data = json.loads((out / "results.json").read_text())
                summary["trials"][name] = trials
                summary["provenance"][f"{name}/{part}"] = data["meta"].get("code_version")
                for pairing in data["pairings"]:
                    key = f"{_spec_name(pairing['pursuer']['source'], variants)} vs "
                    key += _spec_name(pairing["evader"]["source"], variants)
                    row = {**_summary_row(pairing), "part": part}
                    summary["scenes"].setdefault(name, {})[key] = row
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    (args.out / "summary.md").write_text(markdown(summary))
    return summary


def _spec_name(source: str, variants: dict[str, str]) -> str:
    if source in variants:
        return variants[source]
    return Path(source).name if "/" in source else source


def _summary_row(pairing: dict) -> dict:
    s = pairing["summary"]
    return {
        "success_rate": round(s["success_rate"], 3),
        "success_rate_ci95": round(s["success_rate_ci95"], 3),
        "per_evader_cost": round(s["per_evader_cost"], 3),
        "per_evader_cost_ci95": [round(x, 3) for x in s["per_evader_cost_ci95"]],
        "pursuers_lost_to_teammates": round(s["pursuers_teammate"], 2),
        "pursuer_travel_m": round(s["travel_distance"], 2),
    }


def markdown(summary: dict) -> str:
    lines = [
        "| scene | trials | pursuers vs evaders | success | per-evader cost | pursuers lost to "
        "teammates | pursuer travel m |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, rows in summary["scenes"].items():
        for key, r in rows.items():
            lo, hi = r["per_evader_cost_ci95"]
            lines.append(
                f"| {name} | {summary['trials'][name]} | {key} | {r['success_rate']:.3f} ± "
                f"{r['success_rate_ci95']:.3f} | {r['per_evader_cost']:.3f} [{lo:.3f}, {hi:.3f}] "
                f"| {r['pursuers_lost_to_teammates']:.2f} | {r['pursuer_travel_m']:.2f} |"
            )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    play(tyro.cli(Args))
