"""Reproduce the paper's Tables II-VI: train co-evolutions, cross-confront, write the tables.

    pe-mjx reproduce --fraction 0.01           # a quick look: 1% of 10M env steps
    pe-mjx reproduce                           # the full 10 million per run
    pe-mjx reproduce --skip-train --runs runs  # evaluate existing runs only
    pe-mjx reproduce --skip-train --runs assets/policies --tables III V VI \\
        --transfer-evaders pursuers            # the shipped 20-5-8 policies (docs/results.md)
    pe-mjx reproduce --only mix-20-5-8 --stop-after 50 --skip-eval
                                               # one run, 50 iterations per call (resumable)

Resumable: training resumes every run that has a checkpoint from there (so the command can be
repeated, e.g. in chunks of --stop-after iterations, until every run is done: the tables are
evaluated once no run it trained is left unfinished), and a table whose results.json
exists is not evaluated again (delete it to redo it; with `--extend`, only the pairings of runs
found since are played, the others kept once one of them replays the same game). Tables II-IV:
at each scale, every pursuit policy against every evasion policy of another co-evolution at that
scale. Tables V and VI: the pursuit policies trained at 20-5-8 against the evasion policies
trained at 16-4-4 and 24-6-12, in those scenes (generalization); with `--transfer-evaders
pursuers` they meet the evasion policies trained at 20-5-8 instead (both teams transferred; the
paper's numbers beside them are then for a different opponent, and the report says so).
The paper's numbers stand beside ours.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import re
from pathlib import Path
from typing import Literal

from pe_mjx.experiment import Backend
from pe_mjx.names import ENCODERS, TEAMS
from pe_mjx.paper import ENV_STEPS, PAPER, TABLES, paper_runs

TableName = Literal[tuple(TABLES)]  # type: ignore[valid-type]
EncoderName = Literal[tuple(ENCODERS)]  # type: ignore[valid-type]


@dataclasses.dataclass(frozen=True)
class ReproduceArgs:
    """Train the paper's co-evolutions and write our Tables II-VI beside the paper's."""

    runs: Path = Path("runs")
    """Where the co-evolution runs live (<runs>/<encoder>-<preset><suffix>)."""
    suffix: str = ""
    """Appended to every run's name (<encoder>-<preset><suffix>): "-3m" evaluates the shipped
    policies trained to 3M env steps (assets/policies/mix-20-5-8-3m, ...)."""
    out: Path = Path("results/paper")
    """Per-table evaluation outputs."""
    docs: Path = Path("docs/paper_tables.md")
    """The report with our tables beside the paper's (docs/results.md quotes and discusses it)."""
    fraction: float = 1.0
    """Training budget as a fraction of the paper's 10 million env steps per run."""
    env_steps: int | None = None
    """Training budget per run in env steps (instead of --fraction)."""
    only: tuple[str, ...] = ()
    """Train these runs (e.g. mix-20-5-8) instead of those the chosen tables use."""
    stop_after: int | None = None
    """Train each run at most this many iterations in this call (then checkpoint and move on;
    repeat the command to go on); the tables wait until no run is left unfinished."""
    train_seed: int = 0
    """Seed of the training runs (--seed is the evaluation trials')."""
    skip_train: bool = False
    """Evaluate the runs that exist; train nothing."""
    skip_eval: bool = False
    """Train only; evaluate no table and write no report."""
    encoders: tuple[EncoderName, ...] = ENCODERS
    """The methods whose co-evolutions are trained and confronted."""
    tables: tuple[TableName, ...] = tuple(TABLES)
    """The paper's tables to reproduce."""
    trials: int = 100
    """Episodes per pairing."""
    backend: Backend = "mjx"
    """Env backend for training and evaluation."""
    seed: int = 0
    """Seed of the evaluation trials."""
    baselines: tuple[TableName, ...] = ()
    """Tables that also get each co-evolution against itself and the scripted teams on both
    sides (cells the paper has not are shown as "-")."""
    transfer_evaders: Literal["paper", "pursuers"] = "paper"
    """Tables V and VI: evaders trained at the scene's scale (the paper) or at the pursuers'
    scale, 20-5-8 (when the 16-4-4 and 24-6-12 co-evolutions have not been trained)."""
    extend: bool = False
    """A table whose results.json exists but lacks runs found since (a method added) is played
    again keeping its pairings of unchanged policies (same fingerprints): one of them is
    replayed and must come out the same trial for trial (distances up to float32 rounding),
    then only the new pairings are played (if it differs, the whole table is). Without it such
    a table is kept as it is."""
    progress: bool = True
    """Show the training progress bar and each pairing's (on a terminal, on stderr); off for
    logs of long unattended runs."""

    def __post_init__(self) -> None:
        if not 0 < self.fraction <= 1:
            raise ValueError(f"--fraction must be in (0, 1], got {self.fraction}")
        if self.env_steps is not None and self.env_steps < 1:
            raise ValueError(f"--env-steps must be >= 1, got {self.env_steps}")
        if self.stop_after is not None and self.stop_after < 1:
            raise ValueError(f"--stop-after must be >= 1, got {self.stop_after}")
        if not 0 <= self.train_seed < 2**32:
            raise ValueError(f"--train-seed must be in [0, 2**32), got {self.train_seed}")
        from pe_mjx.eval_config import MAX_TRIALS

        if not 1 <= self.trials <= MAX_TRIALS:  # before hours of training, not after
            raise ValueError(f"--trials must be in 1..{MAX_TRIALS}, got {self.trials}")
        if not re.fullmatch(r"[A-Za-z0-9._-]*", self.suffix):
            raise ValueError(
                f"--suffix may hold only letters, digits, '.', '_' and '-', got {self.suffix!r}"
            )
        unknown = sorted(set(self.only) - set(paper_runs()))
        if unknown:
            raise ValueError(
                f"--only: unknown runs {', '.join(unknown)}; known: {', '.join(paper_runs())}"
            )

    @property
    def budget(self) -> int:
        """Env steps per training run."""
        return self.env_steps or max(1, int(ENV_STEPS * self.fraction))


def table_scales(table: str, transfer_evaders: str = "paper") -> tuple[str, str, str]:
    """(scene, pursuers' training scale, evaders' training scale) of one table."""
    scene, p_scale, e_scale = TABLES[table]
    return scene, p_scale, p_scale if transfer_evaders == "pursuers" else e_scale


def method_of(source: str) -> str:
    """The method of a policy source in the runs' layout (<encoder>-<preset>...; "scripted")."""
    return Path(source).name.split("-")[0]


def _train(args: ReproduceArgs) -> bool:
    """Trains (or resumes) the runs the tables use (or --only's); whether all are done."""
    from pe_mjx.policy import store
    from pe_mjx.ppo.run import train

    budget = args.budget
    scales = {s for t in args.tables for s in table_scales(t, args.transfer_evaders)[1:]}
    finished = True
    for name, config in paper_runs(budget, args.backend, args.train_seed).items():
        if args.only:
            if name not in args.only:
                continue
        elif config.pursuer.network.encoder not in args.encoders or config.preset not in scales:
            continue  # only the co-evolutions that the chosen tables use
        out = args.runs / f"{name}{args.suffix}"
        resume = (out / store.CHECKPOINT_DIR).exists()
        if resume and store.read_meta(out)["env_steps"] >= budget:
            continue
        how = "resuming" if resume else "starting"
        print(f"training {out.name} ({budget:,} env steps, {how})", flush=True)
        _, state = train(
            config, out, resume=resume, stop_after=args.stop_after, progress=args.progress
        )
        finished = finished and int(state.env_steps) >= budget
    return finished


def found_runs(args: ReproduceArgs, scale: str) -> list[str]:
    """The runs of the chosen methods trained at `scale` that have a checkpoint, as sources."""
    from pe_mjx.policy import store

    found = []
    for encoder in args.encoders:
        run = args.runs / f"{encoder}-{scale}{args.suffix}"
        try:
            store.read_meta(run)
        except store.CheckpointError:
            continue
        found.append(str(run))
    return found


def _evaluate(args: ReproduceArgs) -> dict[str, dict]:
    from pe_mjx.evaluate import evaluate

    done = {}
    for table in args.tables:
        scene, p_scale, e_scale = table_scales(table, args.transfer_evaders)
        out = args.out / f"table-{table}"
        pursuers, evaders = found_runs(args, p_scale), found_runs(args, e_scale)
        keep = None
        if (out / "results.json").exists():
            done[table] = _read_results(out / "results.json")
            played = {p[team]["source"] for p in done[table]["pairings"] for team in TEAMS}
            unplayed = sorted(set(pursuers + evaders) - played)
            if unplayed and args.extend:
                print(f"table {table}: extending {out / 'results.json'} with {', '.join(unplayed)}")
                keep = out
            else:
                if unplayed:  # kept as it is, but not silently stale
                    print(
                        f"table {table}: kept {out / 'results.json'}, which does not play "
                        f"{', '.join(unplayed)}; add --extend to play them (or delete {out})"
                    )
                continue

        if not pursuers or not evaders:
            print(f"table {table}: no runs for it yet, skipped")
            continue
        full = table in args.baselines
        if full:
            pursuers, evaders = [*pursuers, "scripted"], [*evaders, "scripted"]
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
            skip_same_method=not full,
            keep=keep,
            progress=args.progress,
        )
        done[table] = _read_results(out / "results.json")
    return done


def _read_results(path: Path) -> dict:
    """An evaluation's results.json (read with a cap; a ValueError naming it if it is not one)."""
    from pe_mjx import outputs
    from pe_mjx.evaluate import MAX_RESULTS_BYTES

    try:
        data = json.loads(outputs.read_text(path, MAX_RESULTS_BYTES))
        if not isinstance(data, dict) or not isinstance(data.get("pairings"), list):
            raise ValueError("no pairings")
    except ValueError as err:
        raise ValueError(
            f"{path}: not an evaluation's results ({err}); delete it to redo it"
        ) from None
    return data


def _budgets(done: dict[str, dict]) -> list[str]:
    """One line per learned policy in the tables: its training env steps."""
    from pe_mjx.policy import store

    sources = sorted(
        {p[team]["source"] for d in done.values() for p in d["pairings"] for team in TEAMS}
        - {"scripted", "random"}
    )
    lines = []
    for source in sources:
        try:
            steps = f"{store.read_meta(source)['env_steps']:,} env steps"
        except store.CheckpointError:
            steps = "not found here"
        lines.append(f"- `{source}`: {steps}")
    return lines


def _report(args: ReproduceArgs, done: dict[str, dict]) -> str:
    from pe_mjx.evaluate import MLP_PADDED_NOTE

    budget = (
        "the policies as found (their training budgets are listed below)"
        if args.skip_train
        else f"{args.fraction:g} x 10M env steps per co-evolution"
        if args.env_steps is None
        else f"{args.env_steps:,} env steps per co-evolution"
    )
    lines = [
        "# Paper reproduction: Tables II-VI",
        "",
        f"Written by `pe-mjx reproduce` on {datetime.date.today()}; training budget: {budget}; "
        f"{args.trials} trials per pairing, backend {args.backend}. Each cell: ours / paper. "
        "Per-evader cost is mean(m')/mean(n').",
        "",
    ]
    if args.skip_train:
        lines += [*_budgets(done), ""]
    runs = f"; runs `<encoder>-<scale>{args.suffix}`" if args.suffix else ""
    for table, data in done.items():
        scene, p_scale, e_scale = table_scales(table, args.transfer_evaders)
        lines += [
            f"## Table {table}: scene {scene} "
            f"(pursuers trained at {p_scale}, evaders at {e_scale}{runs})",
            "",
        ]
        if e_scale != TABLES[table][2]:
            lines += [
                f"The evaders were trained at {e_scale}, not at {TABLES[table][2]} as in the "
                "paper; the paper's numbers beside ours are against its evaders.",
                "",
            ]
        if table in args.baselines:
            lines += [
                "Also each co-evolution against itself and the scripted teams "
                '("-": the paper has no such cell).',
                "",
            ]
        lines += [
            "| Evader | Pursuer | Success rate | Travel distance | Pursuit cost "
            "| Per-evader cost |",
            "|---|---|---|---|---|---|",
        ]
        for pairing in data["pairings"]:
            e_method = method_of(pairing["evader"]["source"])
            p_method = method_of(pairing["pursuer"]["source"])
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
        if any(p[t].get("note") == "mlp-padded" for p in data["pairings"] for t in TEAMS):
            lines += ["", MLP_PADDED_NOTE]
        lines.append("")
    if not done:
        lines.append("No table has been evaluated yet.")
    return "\n".join(lines) + "\n"


def reproduce(args: ReproduceArgs) -> Path | None:
    """Trains what the chosen tables need, evaluates them, writes the report; returns its path
    (None when nothing was evaluated: --skip-eval, or runs left unfinished by --stop-after)."""
    from pe_mjx import outputs

    if args.docs.parent.is_dir():  # a --docs that cannot be written: said before any work
        outputs.check_target(args.docs, force=True, flag="--docs")
    finished = args.skip_train or _train(args)
    if args.skip_eval or not finished:
        if not finished:
            print("some runs are unfinished (--stop-after): run the command again to go on")
        return None
    done = _evaluate(args)
    if not done:  # an empty report never replaces the user's --docs
        suffix = f" (suffix {args.suffix!r})" if args.suffix else ""
        raise ValueError(
            f"--runs: {args.runs} holds no run with a checkpoint for table(s) "
            f"{', '.join(args.tables)}{suffix}; nothing to report, {args.docs} is left as it was"
        )
    args.docs.parent.mkdir(parents=True, exist_ok=True)
    outputs.write_file(args.docs, _report(args, done), force=True, flag="--docs")
    return args.docs
