"""docs/results.md's recipe as data: where it departs from the paper or fills what the paper
leaves open, its hyperparameters beside the paper's, and what each of the page's tables cost.

    python -m experiments.results.recipe [--out docs/data/recipe]

Reads the code's defaults (`pe_mjx.experiment.default_config("20-5-8")`), the config and the
curves of every committed run (`train/runs/*/config.json`, `curves.csv.xz`), the evaluation
reports each table of the page is read from (the policies they played, `meta.seconds`), and
the committed measurements a deviation cites (the evader diagnosis, the ablations, the seed
spread); beside them `pe_mjx.paper.SETTINGS`, what the paper says of each setting, in its own
words, and `pe_mjx.paper.hyperparameters`, the defaults' settings beside them. Writes
OUT/recipe.json and three tables, OUT/deviations.md, OUT/hyperparameters.md and OUT/compute.md,
which docs/results.md quotes row for row (the links of these files point from OUT; the page's,
the same rows, from docs/).

Training time: `pe_mjx.ppo.curves.training_time` of each run's rows (recipe.json gives per run
the longest interval counted and the shortest pause): wall hours of the project's 2-core CPU,
mostly shared with other jobs, so more than a run alone would take.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import tyro

from pe_mjx.eval_reports import code_provenance, evaluation_seconds, provenance_text
from pe_mjx.experiment import ExperimentConfig, default_config
from pe_mjx.names import ENCODERS
from pe_mjx.paper import PAPER as PAPER_TABLES
from pe_mjx.paper import SETTINGS, hyperparameters, learning_rate, says, step_size
from pe_mjx.policy.ship import derived_source
from pe_mjx.ppo import curves
from pe_mjx.ppo.curves import CURVES_FILE, PAUSE_S, read_rows

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "docs" / "data"
RUNS = ROOT / "train" / "runs"
SCENES_BEYOND = ("240-60-120", "120-30-60", "60-15-30", "20-5-8")
"""The scenes of the page's 240-60-120 table (experiments/results/large_scale.py's)."""
# The evaluations each table of docs/results.md is read from (globs under docs/data; its test,
# tests/test_results_doc.py, reads Tables II-VI from the same).
TABLES = {
    "II": ("paper-3m-scales/table-II",),
    "III": ("paper-3m/table-III",),
    "III at 10M": ("paper-10m/table-III",),
    "Best responses at 20-5-8": ("best-responses-20-5-8",),
    "IV": ("paper-3m-scales/table-IV",),
    "V": ("paper-3m-scales/table-V",),
    "VI": ("paper-3m-scales/table-VI",),
    "Three seeds at 20-5-8": ("coev-seeds-3m/*-s[0-9]",),
    "Table III, seeds 1 and 2": ("paper-3m-s[0-9]/table-III",),  # seed 0's: Table III's row
    # The parts of experiments/results/large_scale.py that the page's table quotes, and the two
    # single evaluations beside it (the full-attention transfer and the picture's replay).
    "240-60-120": (
        *(f"large-scale/240-60-120/{p}" for p in ("main", "tuned-evader-240", "next-evader")),
        *(f"large-scale/{s}/tuned-pursuer-5m" for s in SCENES_BEYOND),
        "large-scale/20-5-8/tuned-pursuer",
        "transfer-240-60-120-3m",
        "arena-240-60-120",
    ),
    "Ablations": ("ablations/*",),
    "240-60-120 over three seeds": ("flagship-seeds/s[0-9]",),
    "Opponent pools at 20-5-8": ("pool-3m",),
}
LEADERBOARDS = "Leaderboards"
"""The compute row of the files the committed leaderboards pool (each `leaderboard.json`'s
sources) beyond those of the tables above, which count in their own rows."""
# A policy shipped from a seed-0 co-evolution (`mix-20-5-8-3m`), or the same parameters read
# through k nearest entities or a 5 m length unit (`mix-20-5-8-3m-k4-5m`).
SHIPPED = re.compile(r"(?P<run>[a-z]+-\d+-\d+-\d+)-3m(-k\d+)?(-5m)?")
DIAGNOSIS = {"flee": "d7-flee10", "flee_and_step": "d9-at-300k"}
LENGTH = "eval/evader_vs_scripted/length"
NOTES = "../../experiments"  # docs/experiments, from docs/data/recipe
DOCS = "../.."  # docs, from docs/data/recipe


@dataclasses.dataclass(frozen=True)
class Args:
    out: Path = DATA / "recipe"
    """Where recipe.json, deviations.md, hyperparameters.md and compute.md go."""


def and_list(words: list[str]) -> str:
    return " and ".join([", ".join(words[:-1]), words[-1]] if len(words) > 1 else words)


def num(x: float) -> str:
    return f"{x:g}"


def read_json(path: Path) -> dict:
    return json.loads(path.read_text())


def experiment(run: Path) -> ExperimentConfig:
    return ExperimentConfig.from_dict(read_json(run / "config.json")["experiment"])


def co_evolutions() -> dict[str, ExperimentConfig]:
    """The seed-0 co-evolutions of Tables II-VI (`train/runs/<encoder>-<scale>-s0`)."""
    return {run.name: experiment(run) for run in sorted(RUNS.glob("*-s0"))}


def recipe_differences(runs: dict[str, ExperimentConfig]) -> list[str]:
    """The fields in which any co-evolution departs from `default_config` of its scene."""
    return sorted({f for c in runs.values() for f in default_config(c.preset).differences(c)})


def run_of(spec: str) -> str | None:
    """The directory under train/runs whose curves trained the policy `spec` (a run, a shipped
    name or a path), or None where no committed run logged it (train/seeds keeps policies only)."""
    name = Path(spec).name
    if (RUNS / name / CURVES_FILE).is_file():
        return name
    shipped = RUNS / name / "config.json"  # `pe-mjx ship --nearest-k` of a run: that run's
    source = derived_source(read_json(shipped)) if shipped.is_file() else None
    if source is not None:
        return run_of(source)
    if Path(spec).parent.name == "10m" and (RUNS / f"{name}-10m" / CURVES_FILE).is_file():
        return f"{name}-10m"  # trained under runs/10m/<run>, kept as train/runs/<run>-10m
    match = SHIPPED.fullmatch(name)
    if match is None:
        return None
    run, shipped = f"{match['run']}-s0", ROOT / "assets" / "policies" / f"{match['run']}-3m"
    if experiment(shipped) != experiment(RUNS / run):
        raise SystemExit(f"recipe: error: {shipped} is not the policy of train/runs/{run}")
    return run


def compute() -> dict:
    """Per table of the page: the runs that trained its policies and its evaluations' time."""
    tables = {}
    reports_of = {
        t: sorted(p for g in gs for p in DATA.glob(f"{g}/results.json")) for t, gs in TABLES.items()
    }
    counted = {p for reports in reports_of.values() for p in reports}
    boards = sorted(DATA.glob("leaderboards/*/leaderboard.json"))
    pooled = {ROOT / s["path"] for board in boards for s in read_json(board)["sources"]}
    reports_of[LEADERBOARDS] = sorted(pooled - counted)
    for table, reports in reports_of.items():
        results = [read_json(p) for p in reports]
        metas = [r["meta"] for r in results]
        specs = {s for m in metas for s in m["pursuers"] + m["evaders"]} - {"scripted", "random"}
        trained_by = {spec: run_of(spec) for spec in specs}
        tables[table] = {
            "evaluations": [str(p.parent.relative_to(DATA)) for p in reports],
            "evaluation_h": sum(evaluation_seconds(r) for r in results) / 3600,
            "devices": sorted({d for m in metas for d in m["devices"]}),
            "runs": sorted({r for r in trained_by.values() if r}),
            "not_logged": sorted(Path(s).name for s, r in trained_by.items() if r is None),
            "provenance": code_provenance(metas),
        }
    used = sorted({r for t in tables.values() for r in t["runs"]})
    logged = sorted(path.parent.name for path in RUNS.glob(f"*/{CURVES_FILE}"))
    runs = {r: curves.training_time(read_rows(RUNS / r / CURVES_FILE), PAUSE_S) for r in logged}
    page = {"runs": used, "evaluation_h": sum(t["evaluation_h"] for t in tables.values())}
    other = {"runs": sorted(set(runs) - set(used)), "evaluation_h": 0.0}
    for t in (*tables.values(), page, other):
        t["training_h"] = round(sum(runs[r]["hours"] for r in t["runs"]), 2)
        t["evaluation_h"] = round(t["evaluation_h"], 2)
        t["total_h"] = round(t["training_h"] + t["evaluation_h"], 2)
    cores = read_json(ROOT / "docs" / "bench_train.json")["machine"]["cores"]
    return {
        "pause_s": PAUSE_S,
        "machine": {"cpu_cores": cores, "gpu": None},
        "runs": runs,
        "tables": tables,
        "page": page,
        "in_no_table": other,
    }


def measurements() -> dict:
    """The committed numbers the deviations table cites, each with the file it is read from."""
    diagnosis = {r["run"]: r for r in read_json(DATA / "evader_diagnosis.json")}
    reference = read_json(DATA / "evader_diagnosis_reference.json")["experiment"]
    ablations = DATA / "ablations" / "effects.json"  # experiments/results/ablations.py
    spread = {}  # the methods with three seeds at 20-5-8, in the page's order
    for method in [m for m in ENCODERS if (DATA / "coev-seeds-3m" / m / "seeds.json").is_file()]:
        label = f"{method.upper()}(20,5,8)"
        rows = read_json(DATA / "coev-seeds-3m" / method / "seeds.json")["pairings"]
        row = next(r for r in rows if (r["pursuer"], r["evader"]) == (f"P_{label}", f"E_{label}"))
        spread[method] = row["success_rate"]["std"]
    return {
        "evader_diagnosis": {
            "source": "docs/data/evader_diagnosis.json",
            "reference_learning_rate": reference["ppo"]["learning_rate"],
            **{
                key: {
                    "changed": diagnosis[run]["changed"],
                    "length": diagnosis[run]["curves"][LENGTH],
                }
                for key, run in DIAGNOSIS.items()
            },
        },
        "ablations": read_json(ablations) if ablations.is_file() else {},
        "seeds": {
            "source": f"docs/data/coev-seeds-3m/{{{','.join(spread)}}}/seeds.json",
            "self_match_success_std": spread,
        },
    }


def episode_length(curve: dict) -> str:
    return f"{curve['first']:.1f} → {curve['last']:.1f} steps in {curve['last_step']:,} env steps"


def deviations(
    config: ExperimentConfig, runs: dict[str, ExperimentConfig], measured: dict, env_steps: int
) -> list[dict]:
    """Rows (what, ours, paper, why, measured): every place the recipe departs from the paper
    or fills what it leaves open."""
    rows = [
        *evader_rows(config, measured["evader_diagnosis"], measured["ablations"]),
        *training_rows(config, runs, measured, env_steps),
        *evaluation_rows(),
    ]
    keys = ("what", "ours", "paper", "why", "measured")
    return [dict(zip(keys, row, strict=True)) for row in rows]


def evader_rows(
    config: ExperimentConfig, diagnosis: dict, ablations: dict
) -> list[tuple[str, ...]]:
    """The step size and the flee shaping that made the evaders learn, and the rewards."""
    reward = config.env.reward
    paper = ablations.get("paper_recipe", {}).get("text")
    no_data = "the step size without the shaping: not yet ablated"
    fast = diagnosis["flee_and_step"]["changed"]
    fast_rate, fast_schedule = step_size(fast["ppo.learning_rate"]), fast["ppo.lr_schedule"]
    slow = step_size(diagnosis["reference_learning_rate"])
    note = f"[evader diagnosis]({NOTES}/2026-12-01-evader-diagnosis.md)"
    flee = episode_length(diagnosis["flee"]["length"])
    no_shaping = f"at {fast_rate} without it: not yet ablated"
    return [
        (
            "Adam step size",
            f"evaders {step_size(learning_rate(config, 'evader'))}, "
            f"pursuers {step_size(learning_rate(config, 'pursuer'))}",
            f"{says('learning_rate')} ({slow}, this project's first default, is often read "
            "as the paper's)",
            f"at {slow} the evaders' PPO updates barely moved their policy ({note})",
            "with the flee shaping, the eval episode length against the scripted pursuers: "
            f"{episode_length(diagnosis['flee_and_step']['length'])} at {fast_rate} "
            f"({fast_schedule}), {flee} at {slow} (`evader_diagnosis.json`); " + (paper or no_data),
        ),
        (
            "Evaders' flee shaping (`env.reward.evader_flee`)",
            f"{num(reward.evader_flee)} per metre gained from the nearest pursuer, up to "
            f"{num(reward.flee_range)} m; in training only",
            says("evader_reward"),
            f"a dense signal to run, with the larger step size ({note})",
            f"alone, at {slow}: {flee}, no gain; "
            + ("undone with the step size: the row above" if paper else no_shaping),
        ),
        (
            "Capture reward r_s",
            f"{num(reward.capture)} per evader to its captor",
            says("capture"),
            "it must outweigh shadowing an evader at d_cap over the discounted horizon; at 50 "
            f"the pursuers followed and did not capture ([design]({DOCS}/design.md))",
            "not yet ablated at the paper's scales (a 4-1-2 probe in docs/design.md, no data file)",
        ),
        (
            "Other reward constants",
            f"r_c {num(reward.collision)}, d_danger {num(reward.danger_distance)} m, "
            f"d_cap {num(reward.capture_distance)} m, r_e {num(reward.evader_alive)}",
            says("reward_constants"),
            "the paper gives none; SPEC: values that train",
            "not yet ablated",
        ),
    ]


def training_rows(
    config: ExperimentConfig, runs: dict[str, ExperimentConfig], measured: dict, env_steps: int
) -> list[tuple[str, ...]]:
    """The network, the PPO settings, the backend, the budget and the seeds."""
    ppo = config.ppo
    at_10m = sorted({experiment(run).backend for run in RUNS.glob("*-20-5-8-10m")})
    spread = measured["seeds"]["self_match_success_std"]
    return [
        (
            "MIX queries (`mix_queries`)",
            f"`{config.pursuer.network.mix_queries}`: the agent's own token queries every token",
            says("mix_queries"),
            f"about 6x cheaper on this CPU, the same parameters ([design]({DOCS}/design.md))",
            measured["ablations"].get("queries_all", {}).get("text", "not yet ablated"),
        ),
        (
            "PPO settings, reward scales",
            f"{ppo.num_envs} arenas x {ppo.unroll_length} steps, {ppo.update_epochs} epochs x "
            f"{ppo.num_minibatches} minibatches, entropy {num(ppo.entropy_coef)}, clip "
            f"{num(ppo.clip_epsilon)}, GAE λ {num(ppo.gae_lambda)}, γ {num(ppo.gamma)}, step "
            f"size {ppo.lr_schedule} to 0; rewards x {num(config.pursuer.reward_scale)} "
            f"(pursuers), x {num(config.evader.reward_scale)} (evaders); Hyperparameters below",
            says("ppo"),
            "the paper gives none: common PPO values",
            "not yet ablated",
        ),
        (
            "Backend of the published numbers",
            f"{', '.join(sorted({c.backend for c in runs.values()}))} (exact unicycle arcs) in "
            f"Tables II-VI; {', '.join(at_10m)} in Table III at 10M; the code's default is "
            f"{config.backend}",
            says("backend"),
            "faster on this CPU: training by 14% at 20-5-8, evaluation several times "
            f"([benchmarks]({DOCS}/benchmarks.md))",
            "not yet ablated (Table III at 10M changes the budget as well); a 4-1-2 probe whose "
            f"script was not kept: [benchmarks]({DOCS}/benchmarks.md)",
        ),
        (
            "Budget",
            f"{env_steps:,} env steps per co-evolution",
            says("budget"),
            "CPU time (Compute below); Table III also at 10M, on MJX",
            f"{budget_effect()}; 1M vs 3M: "
            f"[notes of 2026-12-02]({NOTES}/2026-12-02-paper-tables.md)",
        ),
        (
            "Seeds",
            f"seed {', '.join(sorted({str(c.seed) for c in runs.values()}))} for every method "
            f"and scale; {and_list([m.upper() for m in spread])} also 1 and 2 at 20-5-8",
            says("seeds"),
            f"CPU time ([notes of 2026-12-03]({NOTES}/2026-12-03-seeds.md))",
            "std over 3 seeds of a self-match's success at 20-5-8: "
            + ", ".join(f"{std:.3f} ({m.upper()})" for m, std in spread.items()),
        ),
    ]


def budget_effect() -> str:
    """3M against 10M where Table III has both: what each pursuer catches of E_MIX, and what the
    scripted pursuers catch of each learned evader."""

    def success(table: str) -> dict[tuple[str, str], float]:
        """(pursuer, evader) method labels ("P_MIX", "E_scripted") -> success rate."""
        out = {}
        for p in read_json(DATA / TABLES[table][0] / "results.json")["pairings"]:
            pursuer, evader = (p[team]["label"].split("(")[0] for team in ("pursuer", "evader"))
            out[pursuer, evader] = p["summary"]["success_rate"]
        return out

    three, ten = success("III"), success("III at 10M")
    both = sorted(k for k in ten if k in three)
    cells = [f"{p} {three[p, e]:.3f} → {ten[p, e]:.3f}" for p, e in both if e == "E_MIX"]
    scripted = [
        f"{e} {three[p, e]:.3f} → {ten[p, e]:.3f}"
        for p, e in both
        if p == "P_scripted" and e != "E_scripted"
    ]
    return (
        "3M → 10M (Table III at 10M), the pursuers' success against E_MIX: "
        + ", ".join(cells)
        + "; the scripted pursuers' against each learned evader: "
        + ", ".join(scripted)
    )


def evaluation_rows() -> list[tuple[str, ...]]:
    """The evaluation protocol of Tables II-VI, from their reports' `meta`."""
    metas = [
        read_json(DATA / TABLES[t][0] / "results.json")["meta"]
        for t in ("II", "III", "IV", "V", "VI")
    ]
    trials = sorted({m["trials"] for m in metas})
    seeds = sorted({m["seed"] for m in metas})
    assert len(trials) == len(seeds) == 1, (trials, seeds)
    assert not any(p == "mlp" for t in ("V", "VI") for _, p in PAPER_TABLES[t]), "paper's MLP*"
    return [
        (
            "Evaluation",
            f"{trials[0]} trials per pairing, trial seed {seeds[0]}; success ± its 95% "
            "Student-t interval, per-evader cost [95% bootstrap interval]",
            says("evaluation"),
            "the intervals show which differences the trials resolve",
            "not yet ablated (no other trial seed played)",
        ),
        (
            "Per-evader cost",
            "mean(m') / mean(n') over the trials",
            says("per_evader_cost"),
            "the paper's tables are the ratio of the means (SPEC 4)",
            "not an ablation: the definition the paper's tables match",
        ),
        (
            "MLP in another scene",
            "its input zero-padded or cut to its training counts (SPEC 3.1); rows marked *",
            says("mlp_other_scenes"),
            "every pairing of Tables V, VI played",
            "not an ablation: Tables V, VI's MLP* rows",
        ),
    ]


def markdown(title: str, text: str, header: tuple[str, ...], rows: list[tuple]) -> str:
    lines = [f"# {title}", "", text, "", "| " + " | ".join(header) + " |"]
    lines.append("|" + "---|" * len(header))
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def runs_cell(runs: list[str]) -> str:
    """`mix-20-5-8-s0`, `mean-20-5-8-s0` ... as "20-5-8 (mix, mean)", the others by name."""
    scales: dict[str, list[str]] = {}
    others = []
    for run in runs:
        match = re.fullmatch(r"([a-z]+)-(\d+-\d+-\d+)-s0", run)
        if match:
            scales.setdefault(match[2], []).append(match[1])
        else:
            others.append(f"`{run}`")
    cells = [f"{scale} ({', '.join(sorted(e))})" for scale, e in sorted(scales.items())]
    return "; ".join(cells + others)


def compute_markdown(data: dict) -> str:
    labels = {
        name: f"Table {name}" if name.split()[0].isupper() else name for name in data["tables"]
    }
    rows = []
    for label, t in [
        *((labels[name], t) for name, t in data["tables"].items()),
        ("The page, each run once", data["page"]),
        ("In no table", data["in_no_table"]),
    ]:
        trained = runs_cell(t["runs"]) if t is not data["page"] else f"{len(t['runs'])} runs"
        if t.get("not_logged"):
            trained += f"; not logged: {', '.join(f'`{n}`' for n in t['not_logged'])}"
        hours = (f"{t[key]:.2f}" for key in ("training_h", "evaluation_h", "total_h"))
        evaluated = provenance_text(t["provenance"]) if "provenance" in t else ""
        rows.append((label, trained, *hours, evaluated))
    text = (
        f"Wall hours on a {data['machine']['cpu_cores']}-core CPU, no GPU, mostly shared with "
        "other jobs. Training: the intervals between the rows of each run's "
        f"`train/runs/<run>/curves.csv.xz`; one over {data['pause_s'] // 60} minutes is a pause "
        "between resumed chunks and counts as the run's median interval. A table's runs are "
        "those whose policies its evaluations played (shared runs count in each table). "
        "Evaluation: `meta.seconds` of its reports, plus the recorded play time of each "
        "pairing a report kept from an earlier one. Evaluated from: the code version each "
        "report recorded (`meta.code_version`; reports older than that field: not recorded)."
    )
    header = "Table|Trained by (`train/runs/`)|Training h|Evaluation h|Total h|Evaluated from"
    return markdown("Compute per table", text, tuple(header.split("|")), rows)


def build() -> dict:
    """Everything recipe.json holds."""
    config, runs = default_config("20-5-8"), co_evolutions()
    cost = compute()
    env_steps = {cost["runs"][name]["env_steps"] for name in runs}
    assert len(env_steps) == 1, env_steps
    measured = measurements()
    return {
        "written_by": "python -m experiments.results.recipe",
        "paper": {key: {"value": value, "says": words} for key, (value, words) in SETTINGS.items()},
        "defaults": {
            "preset": config.preset,
            "backend": config.backend,
            "learning_rate": {t: learning_rate(config, t) for t in ("pursuer", "evader")},
            "reward_scale": {t: config.team(t).reward_scale for t in ("pursuer", "evader")},
            "network": config.pursuer.network.to_dict(),
            "ppo": dataclasses.asdict(config.ppo),
            "reward": dataclasses.asdict(config.env.reward),
            "control_dt": config.env.control_dt,
            "max_steps": config.env.max_steps,
        },
        "co_evolutions": {
            "runs": sorted(runs),
            "differences_from_default": recipe_differences(runs),
        },
        "measured": measured,
        "deviations": deviations(config, runs, measured, *env_steps),
        "hyperparameters": hyperparameters(config, *env_steps),
        "compute": cost,
    }


def write(data: dict, out: Path) -> list[Path]:
    """recipe.json and the three tables under `out`."""
    out.mkdir(parents=True, exist_ok=True)
    differences = ", ".join(f"`{f}`" for f in data["co_evolutions"]["differences_from_default"])
    files = {
        "recipe.json": json.dumps(data, indent=1, ensure_ascii=False) + "\n",
        "deviations.md": markdown(
            "Deviations from the paper",
            "Ours: the defaults of `pe_mjx/experiment.py` (`default_config`), as every "
            "co-evolution of Tables II-VI ran them. The paper's: its value, in its own words "
            "where it says anything. Measured effect: a committed data file's, else not yet "
            "ablated. Written by `python -m experiments.results.recipe`.",
            ("What", "Ours", "The paper", "Why", "Measured effect"),
            [tuple(row.values()) for row in data["deviations"]],
        ),
        "hyperparameters.md": markdown(
            "Hyperparameters beside the paper's",
            "Every co-evolution of Tables II-VI (`train/runs/*-s0`); each differs from "
            f"`default_config` of its scene only in {differences}. Written by "
            "`python -m experiments.results.recipe`.",
            ("Setting", "Pursuers", "Evaders", "The paper"),
            [tuple(row.values()) for row in data["hyperparameters"]],
        ),
        "compute.md": compute_markdown(data["compute"]),
    }
    for name, text in files.items():
        (out / name).write_text(text, encoding="utf-8")
    return [out / name for name in files]


def main(args: Args) -> None:
    for path in write(build(), args.out):
        print(f"wrote {path}")


if __name__ == "__main__":
    main(tyro.cli(Args))
