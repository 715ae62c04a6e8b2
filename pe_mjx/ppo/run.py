"""The loop around the jitted training iteration: progress, TensorBoard and the compact curves
(`curves.csv.xz`), evaluation, checkpoints.

By role: `pe_mjx.ppo.run_files` writes config.json and reads a run's saved config back (for
`--resume`), `pe_mjx.ppo.loggers` holds the progress columns and the loggers; this module starts
a run (`train`) and runs its iterations (`_Loop`). Its names are re-exported here, where callers
have always imported them from."""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from rich.progress import Progress

from pe_mjx import interrupts
from pe_mjx.config import EnvConfig
from pe_mjx.experiment import ExperimentConfig
from pe_mjx.names import TEAMS
from pe_mjx.policy import store
from pe_mjx.policy.core import Policy
from pe_mjx.policy.resolve import resolve_policy
from pe_mjx.ppo import checkpoint
from pe_mjx.ppo.curves import CurveLog
from pe_mjx.ppo.distributed import barrier, is_primary, lost_process_guard
from pe_mjx.ppo.loggers import NoWriter, closing, import_wandb, note, progress_columns, start_wandb
from pe_mjx.ppo.run_files import (
    CONFIG_FILE,
    MAX_CONFIG_BYTES,
    code_version,
    resume_config,
    saved_config,
    write_config,
)
from pe_mjx.ppo.train import Trainer, TrainState

__all__ = [
    "CONFIG_FILE",
    "MAX_CONFIG_BYTES",
    "Snapshot",
    "TrainingError",
    "code_version",
    "initial_variables",
    "learning_rates",
    "resolve_opponents",
    "resolve_pool_members",
    "resume_config",
    "saved_config",
    "snapshot",
    "train",
    "warm_start",
]


def _compiled_iteration(iteration_fn: Any, state: Any, start: int) -> Any:
    """The training iteration compiled ahead of time; in a group, returned once every process
    has compiled it (`barrier`: the first collective would give up on a process still compiling
    30 s after the others). It takes the state in `Trainer.state_shardings`, as it returns it."""
    compiled = iteration_fn.lower(state).compile()
    barrier(f"pe-mjx/compiled-iteration-{start}")
    return compiled


def resolve_opponents(config: ExperimentConfig) -> dict[str, Policy]:
    """The frozen policy of every team that does not learn ("scripted", "random", a run
    directory or a shipped policy), resolved by `pe_mjx.policy.resolve.resolve_policy`."""
    return {
        team: resolve_policy(config.team(team).policy, team, config.env)
        for team in TEAMS
        if config.team(team).policy != "learn"
    }


def resolve_pool_members(config: ExperimentConfig) -> dict[tuple[str, str], Policy]:
    """The learned fixed members of the config's pools (shipped policies or run directories in
    `pool.fixed`), each resolved for the team that plays it, keyed (team, spec); builtin ones are
    left to the Trainer. A member that cannot play that team here raises a `CheckpointError`
    naming `--pool.fixed`."""
    members = {}
    for team, spec in config.pool.learned_members:
        try:
            members[team, spec] = resolve_policy(spec, team, config.env)
        except store.CheckpointError as err:
            raise store.CheckpointError(f"--pool.fixed: {err}") from None
    return members


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
    statistics, and a fresh optimiser state (the step-size schedule starts over too); a pool's
    snapshots of a warm-started opponent start from its stored policy."""
    teams = dict(state.teams)
    for team, stored in variables.items():
        stored = jax.device_put(stored, trainer.replicated)
        opt_state = jax.jit(trainer.optimizers[team].init, out_shardings=trainer.replicated)(
            stored["params"]
        )
        teams[team] = teams[team].replace(
            params=stored["params"], opt_state=opt_state, normalizer=stored["normalizer"]
        )
    pool = state.pool
    if pool is not None:
        pool = dict(pool)
        for team, team_pool in trainer.pools.items():
            if team_pool.opponent in variables:  # its first snapshot too
                stored = teams[team_pool.opponent]
                pool[team] = team_pool.refill(pool[team], stored.params, stored.normalizer)
        pool = jax.device_put(pool, trainer.state_shardings(state).pool)
    return state.replace(teams=teams, pool=pool)


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
        import_wandb()  # without the extra, fail before any work
    if not resume and checkpoint.has_complete_checkpoint(run_dir):
        raise ValueError(
            f"{run_dir} already holds a run; pass --resume {run_dir} to continue it or "
            f"choose another --out"
        )
    trainer = Trainer(
        config,
        opponents=resolve_opponents(config),
        pool_members=resolve_pool_members(config),
    )
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
    primary = is_primary()  # in a group, process 0 alone writes files and shows progress
    if primary:
        write_config(run_dir, trainer, int(state.iteration))
    writer = SummaryWriter(str(run_dir / "tb")) if primary else NoWriter()
    curves = CurveLog(run_dir, int(state.env_steps) if resume else None) if primary else None
    wandb_run = start_wandb(wandb_project, run_dir, config) if wandb_project and primary else None
    start = int(state.iteration)
    end = (
        config.num_iterations
        if stop_after is None
        else min(config.num_iterations, start + stop_after)
    )
    loop = _Loop(trainer, run_dir, primary, progress and primary, on_iteration)
    loop.last_saved = start if resume else None
    # The loggers are closed also on Ctrl-C, so that the scalars logged so far reach the disk.
    with (
        closing(writer, wandb_run, curves),
        Progress(*progress_columns(), disable=not loop.progress) as bar,
    ):
        loop.sinks = (writer, curves, wandb_run)
        return trainer, loop.run(state, start, end, bar)


class _Loop:
    """The iterations of one `train` call: each is run, checked for NaN and inf, timed,
    evaluated when due, logged, shown and checkpointed when due."""

    def __init__(
        self,
        trainer: Trainer,
        run_dir: Path,
        primary: bool,
        progress: bool,
        on_iteration: Callable[[Snapshot], None] | None,
    ):
        self.trainer, self.run_dir, self.primary, self.progress = (
            trainer,
            run_dir,
            primary,
            progress,
        )
        self.on_iteration = on_iteration
        self.last_saved: int | None = None
        self.sinks: tuple[Any, CurveLog | None, Any] = (NoWriter(), None, None)
        self.evaluate_fn = None  # compiled at the first evaluation
        self.latest_eval: dict[str, float] = {}
        # Wall time of this call's iterations and evaluations (compilation excluded), for
        # `perf/eval_share`: the fraction of the run's time spent in the in-training evaluation.
        self.spent = {"train": 0.0, "eval": 0.0}

    def run(self, state: TrainState, start: int, end: int, bar: Progress) -> TrainState:
        trainer, config = self.trainer, self.trainer.config
        iteration_fn = jax.jit(
            trainer.iteration,
            donate_argnums=0,
            out_shardings=(trainer.state_shardings(state), trainer.replicated),
        )
        self.bar = bar
        self.task = bar.add_task(
            config.preset,
            total=config.num_iterations * config.steps_per_iteration,
            completed=int(state.env_steps),
            speed="",
            success="",
        )
        # The first iteration compiles (a minute for the paper's scenes on a CPU).
        bar.update(self.task, description=f"{config.preset} compiling...")
        if not self.progress and self.primary and start < end:
            note(f"{config.preset}: compiling the training iteration...")
        if start < end:
            iteration_fn = _compiled_iteration(iteration_fn, state, start)
        self.tic = time.perf_counter()
        for it in range(start, end):
            interrupts.check()  # a safe point between compiled iterations (Ctrl-C)
            state, metrics = iteration_fn(state)
            if it == start:
                bar.update(self.task, description=config.preset)
            state = self._after(state, metrics, it, start, end)
        return state

    def _after(self, state: TrainState, metrics: Any, it: int, start: int, end: int) -> TrainState:
        """Everything after iteration `it` ran: checks, timing, evaluation, logs, checkpoint."""
        trainer, config = self.trainer, self.trainer.config
        host = {k: float(v) for k, v in jax.device_get(metrics).items()}
        self._check_finite(host, state, it)
        toc = time.perf_counter()
        speed = config.steps_per_iteration / (toc - self.tic)
        if it > start:  # the first iteration of a call compiles
            self.spent["train"] += toc - self.tic
        self.tic = toc
        host["perf/env_steps_per_s"] = speed
        host["perf/agent_steps_per_s"] = speed * trainer.env_config.num_agents
        done_iters = it + 1
        for team, lr in learning_rates(trainer, done_iters).items():
            host[f"ppo/{team}/learning_rate"] = lr
        total = config.num_iterations
        if config.eval_every and (done_iters % config.eval_every == 0 or done_iters == total):
            host.update(self._evaluate(state, done_iters))
        env_steps = int(state.env_steps)
        self._log(host, env_steps)
        success = self.latest_eval.get("eval/pursuer_vs_scripted/success_rate")
        self.bar.update(
            self.task,
            completed=env_steps,
            speed=f"{speed:,.0f} env-steps/s",
            success="" if success is None else f"success vs scripted {success:.2f}",
        )
        if self.on_iteration is not None:
            self.on_iteration(snapshot(trainer, state, host))
        if done_iters % config.checkpoint_every == 0 or done_iters == end:
            curves = self.sinks[1]
            if curves is not None:  # first: the curves never lag their checkpoint
                curves.flush()
            self.last_saved = checkpoint.save(self.run_dir, trainer, state)
        return state

    def _check_finite(self, host: dict[str, float], state: TrainState, it: int) -> None:
        """`TrainingError` when a loss or a parameter became NaN or inf (nothing is saved)."""
        bad = [k for k, v in host.items() if k.startswith("loss/") and not np.isfinite(v)]
        if not bad and bool(_params_finite(state.teams)):
            return
        kept = (
            "no checkpoint was saved"
            if self.last_saved is None
            else f"the last good checkpoint (iteration {self.last_saved}) is kept"
        )
        raise TrainingError(
            f"training diverged at iteration {it + 1}: "
            f"{', '.join(bad) or 'the parameters'} became NaN or inf; {kept}. Try a lower "
            f"--ppo.learning-rate or --ppo.max-grad-norm"
        )

    def _evaluate(self, state: TrainState, done_iters: int) -> dict[str, float]:
        """The in-training evaluation's scalars (its time is not training throughput)."""
        trainer, preset = self.trainer, self.trainer.config.preset
        at = np.int32(done_iters)  # the evaluation's key is folded from it (in the jit)
        if self.evaluate_fn is None:  # compiled apart, so that its time is not counted
            message = f"{preset}: compiling the evaluation..."
            self.bar.update(self.task, description=message)
            if not self.progress and self.primary:
                note(message)
            self.evaluate_fn = (
                jax.jit(_evaluate_at(trainer), out_shardings=trainer.replicated)
                .lower(state, at)
                .compile()
            )
            barrier(f"pe-mjx/compiled-evaluation-{done_iters}")
        eval_tic = time.perf_counter()
        found = {k: float(v) for k, v in jax.device_get(self.evaluate_fn(state, at)).items()}
        self.latest_eval = found
        self.bar.update(self.task, description=preset)
        self.tic = time.perf_counter()
        self.spent["eval"] += self.tic - eval_tic
        if self.spent["train"] > 0:
            share = self.spent["eval"] / (self.spent["eval"] + self.spent["train"])
            found = {**found, "perf/eval_share": share}
        return found

    def _log(self, host: dict[str, float], env_steps: int) -> None:
        writer, curves, wandb_run = self.sinks
        for k, v in host.items():
            if np.isfinite(v):
                writer.add_scalar(k, v, env_steps)
        if curves is not None:
            curves.add(env_steps, host)
        if wandb_run is not None:
            wandb_run.log({k: v for k, v in host.items() if np.isfinite(v)}, step=env_steps)


def _evaluate_at(trainer: Trainer) -> Callable[[TrainState, jax.Array], dict[str, jax.Array]]:
    """`trainer.evaluate` with its key folded from the iteration inside the jitted function (in
    a group, a key made on the host would live on one process's device only)."""
    seed = trainer.config.seed + 1

    def evaluate(state: TrainState, iteration: jax.Array) -> dict[str, jax.Array]:
        return trainer.evaluate(state, jax.random.fold_in(jax.random.key(seed), iteration))

    return evaluate


def learning_rates(trainer: Trainer, iterations: int) -> dict[str, float]:
    """Each learned team's learning rate after `iterations` iterations (its schedule there)."""
    ppo = trainer.config.ppo
    updates = iterations * ppo.update_epochs * ppo.num_minibatches
    rates = {t: trainer.schedule(t) for t in trainer.learned}
    return {t: float(r(updates) if callable(r) else r) for t, r in rates.items()}
