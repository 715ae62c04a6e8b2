"""The loop around the jitted training iteration: progress, TensorBoard and the compact curves
(`curves.csv.gz`), evaluation, checkpoints."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from pe_mjx.config import EnvConfig
from pe_mjx.experiment import RESUMABLE, ExperimentConfig
from pe_mjx.names import TEAMS
from pe_mjx.policy import store
from pe_mjx.policy.core import Policy
from pe_mjx.policy.resolve import resolve_policy
from pe_mjx.ppo import checkpoint
from pe_mjx.ppo.curves import CurveLog
from pe_mjx.ppo.distributed import barrier, is_primary, lost_process_guard
from pe_mjx.ppo.train import Trainer, TrainState

CONFIG_FILE = "config.json"


def code_version() -> dict[str, Any]:
    """The package version and, in a git checkout, the commit and whether the tree was dirty."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        out: dict[str, Any] = {"pe_mjx": version("pe-mjx")}
    except PackageNotFoundError:
        out = {"pe_mjx": "unknown"}
    root = Path(__file__).resolve().parents[2]
    if (root / ".git").exists():
        try:
            commit = subprocess.run(
                ["git", "-C", str(root), "rev-parse", "HEAD"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            ).stdout.strip()
            dirty = subprocess.run(
                ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            ).stdout.strip()
            out.update(git_commit=commit, git_dirty=bool(dirty))
        except (OSError, subprocess.SubprocessError):
            pass
    return out


MAX_CONFIG_BYTES = 1 << 20  # an earlier config.json read back for its start history


def _earlier_starts(run_dir: Path) -> list[dict[str, Any]]:
    """The `starts` of the run's existing config.json (none if absent, too large or malformed:
    the history is a record, never a reason to stop a run). A config.json written before
    `starts` existed gives its one code version, as a start whose iteration is not known."""
    path = run_dir / CONFIG_FILE
    try:
        if not path.is_file() or path.stat().st_size > MAX_CONFIG_BYTES:
            return []
        saved = json.loads(path.read_text())
        starts = saved.get("starts")
        if starts is None and isinstance(saved.get("code_version"), dict):
            starts = [{"iteration": None, "code_version": saved["code_version"]}]
    except (OSError, ValueError, AttributeError):
        return []
    if not isinstance(starts, list):
        return []
    known = [s for s in starts if isinstance(s, dict) and "iteration" in s]
    return [s for s in known if s["iteration"] is None or isinstance(s["iteration"], int)]


def _write_config(run_dir: Path, trainer: Trainer, start: int) -> None:
    """`config.json`: the whole experiment (rerun it with `pe-mjx train --config`), what it
    resolved to, and the code version; `starts` lists every (re)start of the run with the
    iteration it started from (null: an earlier start not recorded as such) and the code
    version it ran, so a run resumed on newer code keeps the record of the old."""
    version = code_version()
    earlier = _earlier_starts(run_dir) if start else []  # a fresh run starts a new history
    starts = [s for s in earlier if s["iteration"] is None or s["iteration"] < start]
    starts.append({"iteration": start, "code_version": version})
    payload = {
        "experiment": trainer.config.to_dict(),
        "env_config": trainer.env_config.to_dict(),
        "network_configs": {t: c.to_dict() for t, c in trainer.network_configs.items()},
        "code_version": version,
        "starts": starts,
    }
    tmp = run_dir / f"{CONFIG_FILE}.tmp"
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True))
    tmp.replace(run_dir / CONFIG_FILE)


def saved_config(run_dir: str | Path) -> ExperimentConfig:
    """The experiment config saved with a run's latest checkpoint."""
    try:
        return ExperimentConfig.from_dict(checkpoint.read_experiment(run_dir))
    except ValueError as err:
        if isinstance(err, store.CheckpointError):
            raise
        raise store.CheckpointError(f"{run_dir} holds an invalid config: {err}") from None


def _compiled_iteration(iteration_fn: Any, state: Any, start: int) -> Any:
    """The training iteration compiled ahead of time; in a group, returned once every process
    has compiled it (`barrier`: the first collective would give up on a process still compiling
    30 s after the others). It takes the state in `Trainer.state_shardings`, as it returns it."""
    compiled = iteration_fn.lower(state).compile()
    barrier(f"pe-mjx/compiled-iteration-{start}")
    return compiled


def resume_config(
    run_dir: str | Path, requested: ExperimentConfig | None = None
) -> ExperimentConfig:
    """The config a resumed run continues with: the saved one, with the `requested` changes to
    the fields in `RESUMABLE` (budget, intervals) applied. Any other change is refused
    (`ValueError` naming each field): it would change the game, the networks or PPO."""
    saved = saved_config(run_dir)
    if requested is None:
        return saved
    changed = saved.differences(requested)
    refused = [f for f in changed if f not in RESUMABLE]
    if refused:
        raise ValueError(
            f"--resume {run_dir} cannot change {', '.join(refused)}: a resumed run keeps its "
            f"game, networks and PPO settings (only {', '.join(RESUMABLE)} may change); start a "
            f"new run with another --out instead"
        )
    return saved.replace(**{f: getattr(requested, f) for f in changed})


def resolve_opponents(config: ExperimentConfig) -> dict[str, Policy]:
    """The frozen policy of every team that does not learn ("scripted", "random", a run
    directory or a shipped policy), resolved by `pe_mjx.policy.resolve.resolve_policy`."""
    return {
        team: resolve_policy(config.team(team).policy, team, config.env)
        for team in TEAMS
        if config.team(team).policy != "learn"
    }


def initial_variables(trainer: Trainer) -> dict[str, Any]:
    """The stored variables ({"params", "normalizer"}) of each learned team whose config names
    an `init` policy, checked against the shapes this run's network needs (from the abstract
    train state: nothing is compiled)."""
    sources = {t: s for t in trainer.learned if (s := trainer.config.team(t).init) is not None}
    if not sources:
        return {}
    abstract = trainer.abstract_state().teams
    found: dict[str, Any] = {}
    for team, source in sources.items():
        try:
            restored = store.restore_policy_params(source, team, trainer.env_config)
        except store.CheckpointError as err:
            raise store.CheckpointError(f"--{team}.init: {err}") from None
        want = {"params": abstract[team].params, "normalizer": abstract[team].normalizer}
        problem = store.shape_mismatch(restored.variables, want)
        if problem is not None:
            net = trainer.network_configs[team]
            raise store.CheckpointError(
                f"--{team}.init: the {team} policy of {source} ({restored.net_config.encoder}, "
                f"trained at {restored.trained.name}) does not fit this run's {team} network "
                f"({net.encoder} at {trainer.env_config.name}): it {problem}"
            )
        found[team] = restored.variables
    return found


def warm_start(trainer: Trainer, state: TrainState, variables: dict[str, Any]) -> TrainState:
    """`state` with each team of `variables` starting from those parameters and observation
    statistics, and a fresh optimiser state (the step-size schedule starts over too)."""
    teams = dict(state.teams)
    for team, stored in variables.items():
        stored = jax.device_put(stored, trainer.replicated)
        opt_state = jax.jit(trainer.optimizers[team].init, out_shardings=trainer.replicated)(
            stored["params"]
        )
        teams[team] = teams[team].replace(
            params=stored["params"], opt_state=opt_state, normalizer=stored["normalizer"]
        )
    return state.replace(teams=teams)


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """What a watcher of a training run (the live viewer) gets after every iteration: host
    copies of the current policies and counters, never the trainer or its (donated) state."""

    env_config: EnvConfig
    backend: str
    policies: dict[str, Policy]
    """Every team's policy: the learned ones with their current variables on the host (source
    "training"), the fixed ones as configured."""
    iteration: int
    env_steps: int
    metrics: dict[str, float]


def snapshot(trainer: Trainer, state: TrainState, metrics: dict[str, float]) -> Snapshot:
    policies = trainer.policies(state)
    for team in trainer.learned:
        variables = jax.device_get(policies[team].variables)
        policies[team] = dataclasses.replace(policies[team], variables=variables)
    return Snapshot(
        env_config=trainer.env_config,
        backend=trainer.config.backend,
        policies=policies,
        iteration=int(state.iteration),
        env_steps=int(state.env_steps),
        metrics=dict(metrics),
    )


def train(
    config: ExperimentConfig,
    out: str | Path,
    resume: bool = False,
    progress: bool = True,
    stop_after: int | None = None,
    on_iteration: Callable[[Snapshot], None] | None = None,
    wandb_project: str | None = None,
) -> tuple[Trainer, TrainState]:
    """Trains (or resumes) a co-evolution, writing checkpoints and logs to `out`.

    Args:
      config: the run's config (for a resume, use `resume_config`).
      out: the run directory.
      resume: continue from the latest checkpoint in `out`.
      progress: show a progress bar.
      stop_after: stop (with a checkpoint) after this many iterations of this call; for tests
        and for chunked runs on machines with a time limit.
      on_iteration: called after every iteration with a `Snapshot` (the live viewer).
      wandb_project: also log every scalar to this Weights & Biases project (the `wandb`
        extra; `WANDB_MODE=offline` logs without an account).

    The run directory is locked (`checkpoint.lock_run`) while this runs. A NaN or inf in a loss
    or in the parameters stops the run with `TrainingError` before anything non-finite is saved:
    the last checkpoint stays the last good one. A checkpoint that cannot be written raises
    `checkpoint.CheckpointWriteError`.

    In a group of processes (`pe_mjx.ppo.distributed`, initialised before this is called) every
    process calls this with the same arguments: all compute and write their checkpoint shards,
    process 0 alone locks the directory and writes the config, the logs and the progress; a
    process that dies stops the others with `ProcessLostError`.
    """
    run_dir = Path(out)
    if wandb_project is not None:
        _import_wandb()  # without the extra, fail before any work
    if not resume and checkpoint.has_complete_checkpoint(run_dir):
        raise ValueError(
            f"{run_dir} already holds a run; pass --resume {run_dir} to continue it or "
            f"choose another --out"
        )
    trainer = Trainer(config, opponents=resolve_opponents(config))
    if resume:
        if not run_dir.is_dir():
            raise store.CheckpointError(f"no run at {run_dir}: the directory does not exist")
        starts = {}
    else:
        starts = initial_variables(trainer)  # read and checked before anything is written
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise store.CheckpointError(
                f"cannot create the run directory {run_dir}: {err.strerror or err}"
            ) from None
    lock = checkpoint.lock_run(run_dir) if is_primary() else contextlib.nullcontext()
    with lock, lost_process_guard():
        return _train(
            trainer, starts, run_dir, resume, progress, stop_after, on_iteration, wandb_project
        )


class TrainingError(RuntimeError):
    """Training stopped because it went wrong (non-finite losses or parameters)."""


@jax.jit
def _params_finite(teams: dict[str, Any]) -> jax.Array:
    leaves = [x for x in jax.tree.leaves(teams) if jnp.issubdtype(x.dtype, jnp.floating)]
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))


def _train(
    trainer: Trainer,
    starts: dict[str, Any],
    run_dir: Path,
    resume: bool,
    progress: bool,
    stop_after: int | None,
    on_iteration: Callable[[Snapshot], None] | None,
    wandb_project: str | None = None,
) -> tuple[Trainer, TrainState]:
    from tensorboardX import SummaryWriter

    config = trainer.config
    # A fresh run may reuse a directory whose checkpoints/ holds no finished step (a run killed
    # during its first save): orbax ignores and replaces the unfinished temporary steps.
    if resume:
        state = checkpoint.restore_train_state(run_dir, trainer)
    else:
        state = warm_start(trainer, trainer.init(), starts)
    last_saved = int(state.iteration) if resume else None
    primary = is_primary()  # in a group, process 0 alone writes files and shows progress
    progress = progress and primary
    if primary:
        _write_config(run_dir, trainer, int(state.iteration))
    iteration_fn = jax.jit(
        trainer.iteration,
        donate_argnums=0,
        out_shardings=(trainer.state_shardings(state), trainer.replicated),
    )
    evaluate_fn = None  # compiled at the first evaluation
    writer = SummaryWriter(str(run_dir / "tb")) if primary else _NoWriter()
    curves = CurveLog(run_dir, int(state.env_steps) if resume else None) if primary else None
    wandb_run = _start_wandb(wandb_project, run_dir, config) if wandb_project and primary else None
    start = int(state.iteration)
    total = config.num_iterations
    end = total if stop_after is None else min(total, start + stop_after)
    latest_eval: dict[str, float] = {}
    columns = [
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:,}/{task.total:,} env-steps"),
        TextColumn("{task.fields[speed]}"),
        TextColumn("{task.fields[success]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    ]
    steps_done = int(state.env_steps)
    # Wall time of this call's iterations and evaluations (compilation excluded), for
    # `perf/eval_share`: the fraction of the run's time spent in the in-training evaluation.
    spent = {"train": 0.0, "eval": 0.0}
    # The loggers are closed also on Ctrl-C, so that the scalars logged so far reach the disk.
    with _closing(writer, wandb_run, curves), Progress(*columns, disable=not progress) as bar:
        task = bar.add_task(
            config.preset,
            total=total * config.steps_per_iteration,
            completed=steps_done,
            speed="",
            success="",
        )
        # The first iteration compiles (a minute for the paper's scenes on a CPU).
        bar.update(task, description=f"{config.preset} compiling...")
        if not progress and primary and start < end:
            _note(f"{config.preset}: compiling the training iteration...")
        if start < end:
            iteration_fn = _compiled_iteration(iteration_fn, state, start)
        tic = time.perf_counter()
        for it in range(start, end):
            state, metrics = iteration_fn(state)
            if it == start:
                bar.update(task, description=config.preset)
            host = {k: float(v) for k, v in jax.device_get(metrics).items()}
            bad = [k for k, v in host.items() if k.startswith("loss/") and not np.isfinite(v)]
            if bad or not bool(_params_finite(state.teams)):
                kept = (
                    "no checkpoint was saved"
                    if last_saved is None
                    else f"the last good checkpoint (iteration {last_saved}) is kept"
                )
                raise TrainingError(
                    f"training diverged at iteration {it + 1}: "
                    f"{', '.join(bad) or 'the parameters'} became NaN or inf; {kept}. Try a lower "
                    f"--ppo.learning-rate or --ppo.max-grad-norm"
                )
            toc = time.perf_counter()
            speed = config.steps_per_iteration / (toc - tic)
            if it > start:  # the first iteration of a call compiles
                spent["train"] += toc - tic
            tic = toc
            host["perf/env_steps_per_s"] = speed
            n_agents = trainer.env_config.num_agents
            host["perf/agent_steps_per_s"] = speed * n_agents
            done_iters = it + 1
            for team, lr in learning_rates(trainer, done_iters).items():
                host[f"ppo/{team}/learning_rate"] = lr
            if config.eval_every and (done_iters % config.eval_every == 0 or done_iters == total):
                at = np.int32(done_iters)  # the evaluation's key is folded from it (in the jit)
                if evaluate_fn is None:  # compiled apart, so that its time is not counted
                    message = f"{config.preset}: compiling the evaluation..."
                    bar.update(task, description=message)
                    if not progress and primary:
                        _note(message)
                    evaluate_fn = (
                        jax.jit(_evaluate_at(trainer), out_shardings=trainer.replicated)
                        .lower(state, at)
                        .compile()
                    )
                    barrier(f"pe-mjx/compiled-evaluation-{done_iters}")
                eval_tic = time.perf_counter()
                latest_eval = {
                    k: float(v) for k, v in jax.device_get(evaluate_fn(state, at)).items()
                }
                host.update(latest_eval)
                bar.update(task, description=config.preset)
                tic = time.perf_counter()  # evaluation time is not training throughput
                spent["eval"] += tic - eval_tic
                if spent["train"] > 0:
                    host["perf/eval_share"] = spent["eval"] / (spent["eval"] + spent["train"])
            env_steps = int(state.env_steps)
            for k, v in host.items():
                if np.isfinite(v):
                    writer.add_scalar(k, v, env_steps)
            if curves is not None:
                curves.add(env_steps, host)
            if wandb_run is not None:
                wandb_run.log({k: v for k, v in host.items() if np.isfinite(v)}, step=env_steps)
            success = latest_eval.get("eval/pursuer_vs_scripted/success_rate")
            bar.update(
                task,
                completed=env_steps,
                speed=f"{speed:,.0f} env-steps/s",
                success="" if success is None else f"success vs scripted {success:.2f}",
            )
            if on_iteration is not None:
                on_iteration(snapshot(trainer, state, host))
            if done_iters % config.checkpoint_every == 0 or done_iters == end:
                if curves is not None:  # first: the curves never lag their checkpoint
                    curves.flush()
                last_saved = checkpoint.save(run_dir, trainer, state)
    return trainer, state


def _evaluate_at(trainer: Trainer) -> Callable[[TrainState, jax.Array], dict[str, jax.Array]]:
    """`trainer.evaluate` with its key folded from the iteration inside the jitted function (in
    a group, a key made on the host would live on one process's device only)."""
    seed = trainer.config.seed + 1

    def evaluate(state: TrainState, iteration: jax.Array) -> dict[str, jax.Array]:
        return trainer.evaluate(state, jax.random.fold_in(jax.random.key(seed), iteration))

    return evaluate


class _NoWriter:
    """The TensorBoard writer of a process other than 0 in a group: it writes nothing."""

    def add_scalar(self, *args: Any) -> None:
        pass

    def close(self) -> None:
        pass


@contextlib.contextmanager
def _closing(writer: Any, wandb_run: Any, curves: CurveLog | None) -> Iterator[None]:
    """Closes the TensorBoard writer and the W&B run, and writes the curves, however the block
    ends."""
    try:
        yield
    finally:
        writer.close()
        if curves is not None:
            curves.flush()
        if wandb_run is not None:
            wandb_run.finish()


def _note(message: str) -> None:
    """One line on stderr, for runs without the progress bar (logs, `--no-progress`)."""
    print(message, file=sys.stderr, flush=True)


def learning_rates(trainer: Trainer, iterations: int) -> dict[str, float]:
    """Each learned team's learning rate after `iterations` iterations (its schedule there)."""
    ppo = trainer.config.ppo
    updates = iterations * ppo.update_epochs * ppo.num_minibatches
    rates = {t: trainer.schedule(t) for t in trainer.learned}
    return {t: float(r(updates) if callable(r) else r) for t, r in rates.items()}


def _import_wandb() -> Any:
    """The `wandb` module (ValueError without the extra)."""
    try:
        import wandb
    except ImportError:
        raise ValueError(
            "--wandb-project needs Weights & Biases: pip install 'pe-mjx[wandb]'"
        ) from None
    return wandb


def _start_wandb(project: str, run_dir: Path, config: ExperimentConfig) -> Any:
    """A Weights & Biases run logging beside TensorBoard (ValueError without the extra)."""
    return _import_wandb().init(
        project=project,
        name=run_dir.name,
        dir=str(run_dir),
        config=config.to_dict(),
        resume="allow",
    )
