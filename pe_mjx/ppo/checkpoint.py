"""Checkpoints of training (orbax, no pickle): the full train state for `--resume`.

A run directory holds `checkpoints/<iteration>/` with three orbax items:
  * `train`: the whole `TrainState` (parameters, optimiser and normaliser state, the env batch,
    RNG keys as raw key data, counters), so a resumed run continues bit-for-bit;
  * `policy_<team>` and `meta`: what the policy store (`pe_mjx.policy.store`) reads to play a
    learned team, without rebuilding any env or trainer.
This module writes all three and reads the train state back; everything that reads a policy is in
the store. Orbax writes each step into a temporary directory and renames it when complete, so a
kill during a save leaves the previous step loadable; the manager keeps the last `MAX_TO_KEEP`.

A latest checkpoint damaged after the fact (truncated or altered) is one `DamagedCheckpointError`
naming the latest intact earlier one; `fallback=True` (`pe-mjx train --resume RUN
--resume-intact`) resumes from that one and moves the damaged later ones to
`RUN/damaged-checkpoints/<step>` (kept: the run's next saves reuse their step numbers). A
resumable copy (`pe_mjx.ppo.resumable`) restores its learners exactly, its arenas afresh.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from pe_mjx import interrupts
from pe_mjx.names import TEAMS
from pe_mjx.policy.quiet import quiet_logs
from pe_mjx.policy.shipped import resolve_run
from pe_mjx.policy.store import (
    CHECKPOINT_DIR,
    DAMAGED_DIR,
    FORMAT_VERSION,
    RESUMABLE_COPY,
    CheckpointError,
    DamagedCheckpointError,
    all_steps,
    everywhere,
    intact_instead,
    latest_step,
    manager,
    read_meta,
    short_error,
)
from pe_mjx.ppo.distributed import barrier, is_lost_process_error, is_primary
from pe_mjx.ppo.train import Trainer, TrainState


class CheckpointWriteError(CheckpointError):
    """A checkpoint could not be written (the directory became unwritable, the disk is full).

    When orbax itself failed midway, its worker threads may wait forever for signals that never
    come and keep the interpreter from exiting: a command line ends with `os._exit`."""


LOCK_FILE = ".lock"


@contextlib.contextmanager
def lock_run(run_dir: Path) -> Iterator[None]:
    """Holds an exclusive lock on a run directory (`flock` on `run_dir/.lock`) while a trainer
    uses it; a second trainer gets a `CheckpointError`. The kernel releases it when the process
    ends, however it ends."""
    import fcntl

    try:
        fd = os.open(run_dir / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:
        raise CheckpointError(f"{run_dir}: cannot create its lock file: {err.strerror}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise CheckpointError(
                f"{run_dir} is in use by another pe-mjx train (locked); wait for it to end or "
                f"choose another --out"
            ) from None
        yield
    finally:
        os.close(fd)  # releases the lock


def has_complete_checkpoint(run_dir: Path) -> bool:
    """Whether `run_dir/checkpoints` holds a finished step (orbax names a finished step by its
    number; a save that was killed leaves only `<step>.orbax-checkpoint-tmp-*`)."""
    directory = run_dir / CHECKPOINT_DIR
    return directory.is_dir() and any(p.name.isdigit() for p in directory.iterdir())


def _check_writable(directory: Path, step: int) -> None:
    """Writes, syncs and removes a small probe file: an unwritable directory or a full disk is
    reported before orbax starts (its threads hang when a save fails midway)."""
    probe = directory / f".write-probe-{os.getpid()}"
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with open(probe, "wb") as f:
            f.write(b"\0" * 65536)
            f.flush()
            os.fsync(f.fileno())
        probe.unlink()
    except OSError as err:
        with contextlib.suppress(OSError):
            probe.unlink()
        raise CheckpointWriteError(
            f"cannot write checkpoint {step} to {directory}: {err.strerror or err}"
        ) from None


def _is_key(x: Any) -> bool:
    return hasattr(x, "dtype") and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def keys_to_data(tree: Any) -> Any:
    """Typed PRNG keys -> raw uint32 key data (orbax stores plain arrays)."""
    return jax.tree.map(lambda x: jax.random.key_data(x) if _is_key(x) else x, tree)


def data_to_keys(template: Any, tree: Any) -> Any:
    """Inverse of `keys_to_data`, guided by a template that has the typed keys."""
    return jax.tree.map(
        lambda t, x: jax.random.wrap_key_data(x) if _is_key(t) else x, template, tree
    )


def _flat(tree: Any) -> dict[str, Any]:
    """Leaves by position ("l00000", ...), without zero-size ones (orbax refuses to save those;
    a 1-evader scene has an empty teammate axis)."""
    return {f"l{i:05d}": x for i, x in enumerate(jax.tree.leaves(tree)) if np.size(x)}


def _unflat(template: Any, flat: dict[str, Any]) -> Any:
    leaves, treedef = jax.tree.flatten(template)
    values = [
        flat[f"l{i:05d}"] if np.size(t) else np.zeros(t.shape, t.dtype)
        for i, t in enumerate(leaves)
    ]
    return jax.tree.unflatten(treedef, values)


def _save_items(
    mngr: ocp.CheckpointManager,
    step: int,
    train: dict[str, Any],
    meta: dict[str, Any],
    policies: dict[str, Any] | None = None,
) -> None:
    """Writes checkpoint `step`: the flat train item, the metadata and any policy items."""
    mngr.save(
        step,
        args=ocp.args.Composite(
            train=ocp.args.StandardSave(train), **(policies or {}), meta=ocp.args.JsonSave(meta)
        ),
        force=True,
    )
    mngr.wait_until_finished()


def save(run_dir: str | Path, trainer: Trainer, train_state: TrainState) -> int:
    """Writes a checkpoint of `train_state` (blocking); returns its iteration.

    A SIGINT or SIGTERM during the save is held back until it is complete
    (`pe_mjx.interrupts.deferred`), then raised as `KeyboardInterrupt`."""
    run_dir = Path(run_dir)
    step = int(train_state.iteration)
    policies = {
        f"policy_{team}": ocp.args.StandardSave({"params": ts.params, "normalizer": ts.normalizer})
        for team, ts in train_state.teams.items()
    }
    meta = {
        "format_version": FORMAT_VERSION,
        "iteration": step,
        "env_steps": int(train_state.env_steps),
        "experiment": trainer.config.to_dict(),
        "env_config": trainer.env_config.to_dict(),
        "network_configs": {t: c.to_dict() for t, c in trainer.network_configs.items()},
        "num_actions": {t: trainer.env_config.team(t).num_actions for t in TEAMS},
    }
    _check_writable(run_dir / CHECKPOINT_DIR, step)
    try:
        with (
            interrupts.deferred(),
            _lost_process_logs_dropped(),
            manager(run_dir, create=True) as mngr,
        ):
            _save_items(mngr, step, _flat(keys_to_data(train_state)), meta, policies)
    except Exception as err:
        if jax.process_count() > 1 and is_lost_process_error(err):
            # Another process died while this one waited for it at the save's barrier: the
            # same stop as a failed collective (`lost_process_guard` words it).
            raise
        raise CheckpointWriteError(
            f"cannot write checkpoint {step} to {run_dir / CHECKPOINT_DIR}: {short_error(err)}"
        ) from None
    return step


class _DropLostProcessErrors(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        err = record.exc_info[1] if record.exc_info else None
        return err is None or not is_lost_process_error(err)


@contextlib.contextmanager
def _lost_process_logs_dropped() -> Iterator[None]:
    """orbax's save threads log a barrier that failed, traceback and all, before the save
    raises it; when it failed because another process died, the command line's one line says
    so, and the traceback is left out."""
    absl_logger, drop = logging.getLogger("absl"), _DropLostProcessErrors()
    absl_logger.addFilter(drop)
    try:
        yield
    finally:
        absl_logger.removeFilter(drop)


def _require_train_item(run_dir: Path, step: int) -> None:
    if not (run_dir / CHECKPOINT_DIR / str(step) / "train").is_dir():
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} holds policies only (no train state): it can be "
            f"played and evaluated, the run cannot be resumed"
        )


def read_experiment(run_dir: str | Path) -> dict[str, Any]:
    """The experiment config tree (a dict) saved with the latest checkpoint of a resumable run."""
    meta = read_meta(run_dir)
    if meta["format_version"] < 2:
        raise CheckpointError(
            f"{run_dir} was made by an older pe-mjx (checkpoint format {meta['format_version']}): "
            f"its policies can be played and evaluated, the run cannot be resumed"
        )
    _require_train_item(resolve_run(run_dir), meta["step"])
    return meta["experiment"]


def _learners(tree: Any) -> tuple[Any, ...]:
    """What a resumable copy keeps of a train state, in the saved order: the teams (then an
    opponent pool's state, if any) first, the RNG and the counters last."""
    return (tree.teams, tree.pool, tree.rng, tree.iteration, tree.env_steps)


def _with_fresh_arenas(trainer: Trainer, learners: tuple[Any, ...]) -> Any:
    teams, pool, rng, iteration, env_steps = learners
    fresh = jax.device_get(keys_to_data(trainer.init(int(iteration) + trainer.config.seed)))
    return fresh.replace(teams=teams, pool=pool, rng=rng, iteration=iteration, env_steps=env_steps)


def _restore_resumable_copy(run_dir: Path, step: int, trainer: Trainer, abstract: Any) -> Any:
    """Checkpoint `step` of a resumable copy (`pe_mjx.ppo.resumable.write_resumable_copy`): its
    learners, RNG and counters, with freshly drawn arenas."""
    target = _learners(abstract)
    try:
        with quiet_logs(), manager(run_dir, create=False) as mngr:
            saved = mngr.restore(
                step,
                args=ocp.args.Composite(train=ocp.args.StandardRestore(everywhere(_flat(target)))),
            ).train
    except Exception as err:
        raise DamagedCheckpointError(
            f"checkpoint {step} in {run_dir} (a resumable copy) cannot be restored: "
            f"{short_error(err)}"
        ) from None
    learners = _unflat(target, jax.tree.map(np.asarray, saved))
    _warn(
        f"checkpoint {step} of {run_dir} is a resumable copy without arenas: "
        f"resuming its learners, counters and RNG exactly, with freshly drawn arenas"
    )
    return _with_fresh_arenas(trainer, learners)


def _restore_across_versions(
    run_dir: Path, step: int, trainer: Trainer, abstract: Any, first_error: Exception
) -> Any:
    """A train state saved by a pe-mjx whose env state had another structure (e.g. a metric was
    added since): the teams (parameters, optimiser and normaliser state), the RNG and the
    counters are restored; the arenas in flight are drawn afresh. Resuming is then exact for
    the learners but not bit-for-bit for the rollouts, and a warning says so.

    The saved leaves are positional (`_flat`): the teams (then an opponent pool's state, if
    any) come first and the RNG and counters last, so both ends are matched by count and every
    shape is checked.
    """
    learners = (abstract.teams, abstract.pool)
    n_teams = len(jax.tree.leaves(learners))
    tail = [abstract.rng, abstract.iteration, abstract.env_steps]
    try:
        with quiet_logs(), manager(run_dir, create=False) as mngr:
            shapes = mngr.item_metadata(step)["train"]
            saved = mngr.restore(
                step, args=ocp.args.Composite(train=ocp.args.StandardRestore(everywhere(shapes)))
            )
        saved = saved.train
        keys = sorted(saved)
        want_teams = jax.tree.leaves(learners)
        sized = [leaf for leaf in want_teams if math.prod(leaf.shape)]
        team_keys, tail_keys = keys[: len(sized)], keys[-len(tail) :]
        for key, leaf in zip(team_keys, sized, strict=True):
            if tuple(np.shape(saved[key])) != tuple(leaf.shape):
                raise ValueError(f"team leaf {key} has shape {np.shape(saved[key])}")
        for key, leaf in zip(tail_keys, tail, strict=True):
            if tuple(np.shape(saved[key])) != tuple(leaf.shape):
                raise ValueError(f"leaf {key} has shape {np.shape(saved[key])}")
    except Exception as err:
        raise DamagedCheckpointError(
            f"checkpoint {step} in {run_dir} cannot be restored: {short_error(first_error)} (nor "
            f"its learners alone: {short_error(err, 120)})"
        ) from None
    values = iter(np.asarray(saved[k]) for k in team_keys)
    teams, pool = jax.tree.map(
        lambda leaf: next(values) if math.prod(leaf.shape) else np.zeros(leaf.shape, leaf.dtype),
        learners,
    )
    rng, iteration, env_steps = (np.asarray(saved[k]) for k in tail_keys)
    _warn(
        f"{run_dir} was saved by another pe-mjx version whose arena state "
        f"differs ({len(keys)} saved arrays, {n_teams} of them the learners'): resuming its "
        f"learners, counters and RNG with freshly drawn arenas"
    )
    return _with_fresh_arenas(trainer, (teams, pool, rng, iteration, env_steps))


def _restore_step(run_dir: Path, step: int, trainer: Trainer, abstract: Any) -> Any:
    """The train state of checkpoint `step` as host arrays (`abstract`: its key-data shapes);
    `DamagedCheckpointError` when its metadata or train item cannot be read back."""
    meta = read_meta(run_dir, step)
    _require_train_item(run_dir, step)
    if meta.get(RESUMABLE_COPY):
        return _restore_resumable_copy(run_dir, step, trainer, abstract)
    try:
        with quiet_logs(), manager(run_dir, create=False) as mngr:
            restored = mngr.restore(
                step,
                args=ocp.args.Composite(
                    train=ocp.args.StandardRestore(everywhere(_flat(abstract)))
                ),
            ).train
        return _unflat(abstract, jax.tree.map(np.asarray, restored))
    except Exception as err:
        return _restore_across_versions(run_dir, step, trainer, abstract, err)


def _warn(message: str) -> None:
    """One warning line, from process 0 of a group only (every process restores the same)."""
    if is_primary():
        print(f"pe-mjx: warning: {message}", file=sys.stderr)


def _set_aside(run_dir: Path, steps: list[int], err: Exception, intact: int) -> None:
    """Moves the damaged checkpoints `steps` to `run_dir/damaged-checkpoints/` (process 0 of a
    group; the others wait), with one warning line."""
    barrier(f"pe-mjx/resume-intact-{intact}-found")
    if is_primary():
        target = run_dir / DAMAGED_DIR
        target.mkdir(exist_ok=True)
        for step in steps:
            dest, n = target / str(step), 1
            while dest.exists():
                dest, n = target / f"{step}.{n}", n + 1
            (run_dir / CHECKPOINT_DIR / str(step)).rename(dest)
        print(
            f"pe-mjx: warning: {err}; moved checkpoint(s) {', '.join(map(str, steps))} to "
            f"{target} and resuming from checkpoint {intact}",
            file=sys.stderr,
        )
    barrier(f"pe-mjx/resume-intact-{intact}-moved")


def _fall_back(run_dir: Path, err: Exception, read: Any, fallback: bool) -> tuple[int, Any]:
    """After the latest checkpoint failed with `err`: (step, reading) of the latest intact one,
    the damaged ones set aside, with `fallback`; else the `DamagedCheckpointError` naming it."""
    found = intact_instead(run_dir, err, read, fallback, either="can be resumed")
    _set_aside(run_dir, [s for s in all_steps(run_dir) if s > found[0]], err, found[0])
    return found


def _require_same_pool(run_dir: Path, step: int, trainer: Trainer) -> None:
    """A `CheckpointError` (one line) when checkpoint `step` was trained with an opponent pool
    and `trainer` has none, the other way round (runs saved before pools had none), or with the
    pool on another team (their states differ)."""
    experiment = read_meta(run_dir, step).get("experiment") or {}
    saved = (experiment.get("pool") or {}).get("team")
    mine = trainer.config.pool.team
    if saved != mine:
        had = f"with an opponent pool (pool.team {saved})" if saved else "without a pool"
        has = f"has pool.team {mine}" if mine else "has none"
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} was trained {had}, this trainer {has}: resume it "
            "with its saved config"
        )


def restore_train_state(
    run_dir: str | Path, trainer: Trainer, fallback: bool = False
) -> TrainState:
    """The full train state of the latest checkpoint, placed with the trainer's shardings.

    `trainer` is built from the run's saved experiment config. When the latest checkpoint is
    damaged: a `DamagedCheckpointError` naming the latest intact one (one line), or, with
    `fallback`, that one, the damaged later ones moved to `run_dir/damaged-checkpoints/`.
    """
    run_dir = Path(run_dir)
    step = latest_step(run_dir)
    _require_train_item(run_dir, step)
    _require_same_pool(run_dir, step, trainer)
    template = trainer.abstract_state()
    abstract = jax.eval_shape(keys_to_data, template)

    def read(s: int) -> Any:
        return _restore_step(run_dir, s, trainer, abstract)

    try:
        restored = read(step)
    except DamagedCheckpointError as err:
        _, restored = _fall_back(run_dir, err, read, fallback)
    # Host arrays straight onto the trainer's mesh: in a group of processes each takes its shards
    # of the same arrays, so a checkpoint resumes on any number of processes and devices.
    placed = jax.device_put(restored, trainer.state_shardings(restored))
    return data_to_keys(template, placed)


def resume_intact(run_dir: str | Path) -> int:
    """For `pe-mjx train --resume RUN --resume-intact`, before anything reads the run's config:
    when the latest checkpoint cannot be resumed (its metadata or its train state is damaged),
    moves it and any other damaged later one to `RUN/damaged-checkpoints/` with a warning line,
    so that the resume continues from the latest intact checkpoint. Returns that checkpoint's
    step; `CheckpointError` when none is intact."""
    from pe_mjx.experiment import ExperimentConfig

    run_dir = Path(run_dir)

    def read(step: int) -> None:
        experiment = read_meta(run_dir, step).get("experiment")
        try:
            trainer = _shape_trainer(ExperimentConfig.from_dict(experiment))
        except (TypeError, ValueError) as err:
            raise DamagedCheckpointError(
                f"checkpoint {step} in {run_dir} holds an invalid config: {err}"
            ) from None
        _restore_step(
            run_dir, step, trainer, jax.eval_shape(keys_to_data, trainer.abstract_state())
        )

    step = latest_step(run_dir)
    _require_train_item(run_dir, step)
    try:
        read(step)
    except DamagedCheckpointError as err:
        step, _ = _fall_back(run_dir, err, read, fallback=True)
    return step


def resumable_meta(run_dir: Path, step: int | None = None) -> dict[str, Any]:
    """The metadata of checkpoint `step` (default: the latest) of `run_dir`; a `CheckpointError`
    when the run cannot be resumed from it (made by an older pe-mjx, or policies only)."""
    meta = read_meta(run_dir, step)
    if meta["format_version"] < 2:
        raise CheckpointError(f"{run_dir} was made by an older pe-mjx: it cannot be resumed")
    _require_train_item(run_dir, meta["step"])
    return meta


def read_host_state(run_dir: Path, meta: dict[str, Any]) -> Any:
    """The train state of the checkpoint that `meta` (`resumable_meta`) describes, as host
    arrays with RNG keys as key data."""
    from pe_mjx.experiment import ExperimentConfig

    trainer = _shape_trainer(ExperimentConfig.from_dict(meta["experiment"]))
    abstract = jax.eval_shape(keys_to_data, trainer.abstract_state())
    return _restore_step(run_dir, meta["step"], trainer, abstract)


def save_learners(directory: Path, state: Any, meta: dict[str, Any]) -> None:
    """Writes checkpoint `meta["step"]` of a resumable copy under `directory`: the learners, RNG
    and counters of `state` (`read_host_state`), and `meta` marked as a copy's."""
    saved_meta = {k: v for k, v in meta.items() if k != "step"} | {RESUMABLE_COPY: True}
    with quiet_logs(), manager(directory, create=True) as mngr:
        _save_items(mngr, meta["step"], _flat(_learners(state)), saved_meta)


def _shape_trainer(config: Any) -> Trainer:
    """A trainer with the train state's shapes of `config`: a team or a pool member played from
    another run is stood in for by the scripted policy (opponents are not part of the train
    state)."""
    from pe_mjx.names import BUILTIN_POLICIES
    from pe_mjx.policy.scripted import make_policy

    opponents = {
        team: make_policy("scripted", config.env, team)
        for team in TEAMS
        if config.team(team).policy not in ("learn", *BUILTIN_POLICIES)
    }
    members = {
        (team, spec): make_policy("scripted", config.env, team)
        for team, spec in config.pool.learned_members
    }
    return Trainer(config, opponents=opponents, pool_members=members)
