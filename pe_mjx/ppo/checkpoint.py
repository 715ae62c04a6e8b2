"""Checkpoints (orbax, no pickle): the full train state for `--resume`, the policies, and configs.

A run directory holds `checkpoints/<iteration>/` with three orbax items:
  * `train`: the whole `TrainState` (parameters, optimiser and normaliser state, the env batch,
    RNG keys as raw key data, counters), so a resumed run continues bit-for-bit;
  * `policy_<team>`: per learned team, its parameters and observation statistics (what
    `pe_mjx.play.load_policy` reads, without rebuilding any env);
  * `meta`: JSON with the whole experiment config, the env and network configs it resolved to,
    counters and the format version. Format 1 (before the experiment config) is still read for
    playing its policies; only format 2 runs can be resumed.
Orbax writes each step into a temporary directory and renames it when complete, so a kill during
a save leaves the previous step loadable; `CheckpointManager` keeps the last `MAX_TO_KEEP`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NoReturn

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from pe_mjx.agents import dummy_obs, init_normalizer
from pe_mjx.config import EnvConfig
from pe_mjx.experiment import ExperimentConfig
from pe_mjx.names import TEAMS
from pe_mjx.networks import NetworkConfig, make_network
from pe_mjx.ppo.train import Trainer, TrainState
from pe_mjx.shipped import resolve_run

FORMAT_VERSION = 2
READABLE_FORMATS = (1, 2)
MAX_TO_KEEP = 3
CHECKPOINT_DIR = "checkpoints"
# Sane bounds on what a checkpoint's metadata may declare, checked before anything is built from
# it (a crafted `num_agents: 20000` made the loader allocate 9.6 GB).
MAX_ENTITIES = 1000
MAX_LAYER_WIDTH = 4096


class CheckpointError(ValueError):
    """A missing, unreadable or mismatched checkpoint."""


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


def _short(err: Exception, limit: int = 300) -> str:
    text = f"{type(err).__name__}: {err}"
    return text if len(text) <= limit else text[:limit] + " ..."


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silences orbax's and absl's logging while a checkpoint is read: a damaged file is reported
    as one `CheckpointError`, not followed by pages of library tracebacks."""
    loggers = [logging.getLogger(name) for name in ("absl", "orbax", "tensorstore")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


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


def _manager(run_dir: Path, create: bool) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(max_to_keep=MAX_TO_KEEP, create=create)
    return ocp.CheckpointManager(
        (run_dir / CHECKPOINT_DIR).absolute(),
        options=options,
        item_names=("train", "meta", *(f"policy_{t}" for t in TEAMS)),
    )


@contextlib.contextmanager
def _interrupts_deferred() -> Iterator[None]:
    """Holds SIGINT and SIGTERM back until the block is done, then raises `KeyboardInterrupt`
    if one came.

    A Ctrl-C that lands inside an orbax save raises in the main thread while orbax's worker
    threads are midway; they then wait forever for the main thread, and the process hung instead
    of exiting (a flaky CI test, 2026-12). Deferred, the save finishes (it takes well under a
    second for this project's states) and the interrupt stops the run after it, with that
    checkpoint complete. Outside the main thread signals cannot be handled and nothing changes.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.signal(sig, lambda num, _frame: caught.append(num)) for sig in signals}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if caught:  # now do what the signal would have done
        handler = previous[caught[0]]
        if handler == signal.SIG_IGN:
            return
        if callable(handler):  # the command line's handler, or Python's default_int_handler
            handler(caught[0], None)
        raise KeyboardInterrupt  # SIG_DFL, or a handler that did not raise


def save(run_dir: str | Path, trainer: Trainer, train_state: TrainState) -> int:
    """Writes a checkpoint of `train_state` (blocking); returns its iteration.

    A SIGINT or SIGTERM during the save is held back until it is complete
    (`_interrupts_deferred`), then raised as `KeyboardInterrupt`."""
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
        with _interrupts_deferred(), _manager(run_dir, create=True) as mngr:
            mngr.save(
                step,
                args=ocp.args.Composite(
                    train=ocp.args.StandardSave(_flat(keys_to_data(train_state))),
                    **policies,
                    meta=ocp.args.JsonSave(meta),
                ),
                force=True,
            )
            mngr.wait_until_finished()
    except Exception as err:
        raise CheckpointWriteError(
            f"cannot write checkpoint {step} to {run_dir / CHECKPOINT_DIR}: {_short(err)}"
        ) from None
    return step


def _latest_step(run_dir: Path) -> int:
    if not run_dir.exists():
        raise CheckpointError(f"no run at {run_dir}: the directory does not exist")
    if not (run_dir / CHECKPOINT_DIR).is_dir():
        raise CheckpointError(f"{run_dir} holds no checkpoints (no {CHECKPOINT_DIR}/ directory)")
    try:
        with _quiet(), _manager(run_dir, create=False) as mngr:
            step = mngr.latest_step()
    except Exception as err:  # an unreadable directory, a damaged step name
        raise CheckpointError(f"{run_dir}: cannot list its checkpoints: {_short(err)}") from None
    if step is None:
        raise CheckpointError(
            f"{run_dir} holds no complete checkpoint (a run stopped during its first save?); "
            f"`pe-mjx train --out {run_dir}` starts it afresh"
        )
    return step


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_meta(meta: Any, where: str) -> None:
    """Checks a checkpoint's metadata against its schema and sane bounds before anything is
    built from it; raises `CheckpointError` naming the first bad field."""

    def bad(message: str) -> NoReturn:
        raise CheckpointError(f"{where} has invalid metadata: {message}")

    if not isinstance(meta, dict):
        bad("not a JSON object")
    for key in ("format_version", "env_config", "network_configs", "num_actions"):
        if key not in meta:
            bad(f"{key} is missing")
    version = meta["format_version"]
    if not _is_int(version) or version not in READABLE_FORMATS:
        raise CheckpointError(
            f"checkpoint format {version!r} in {where} is not supported (this pe-mjx reads "
            f"formats {READABLE_FORMATS})"
        )
    for key in ("iteration", "env_steps"):
        if key in meta and not (_is_int(meta[key]) and meta[key] >= 0):
            bad(f"{key} must be an integer >= 0, got {meta[key]!r}")
    try:
        env_config = EnvConfig.from_dict(meta["env_config"])
    except (TypeError, ValueError) as err:
        bad(f"env_config: {err}")
    counts = {
        "env_config.pursuer.num_agents": env_config.pursuer.num_agents,
        "env_config.evader.num_agents": env_config.evader.num_agents,
        "env_config.arena.num_obstacles": env_config.arena.num_obstacles,
    }
    for field, count in counts.items():
        if count > MAX_ENTITIES:
            bad(f"{field} is {count}, more than the {MAX_ENTITIES} a checkpoint may hold")
    networks, actions = meta["network_configs"], meta["num_actions"]
    if not isinstance(networks, dict) or not networks or set(networks) - set(TEAMS):
        bad(f"network_configs must map some of {TEAMS} to network configs")
    if not isinstance(actions, dict):
        bad("num_actions must map teams to action counts")
    for team, net in networks.items():
        try:
            net_config = NetworkConfig.from_dict(net)
        except (TypeError, ValueError) as err:
            bad(f"network_configs.{team}: {err}")
        for field in ("width", "hidden"):
            if getattr(net_config, field) > MAX_LAYER_WIDTH:
                bad(f"network_configs.{team}.{field} is above {MAX_LAYER_WIDTH}")
        if (net_config.nearest_k or 0) > MAX_ENTITIES:
            bad(f"network_configs.{team}.nearest_k is above {MAX_ENTITIES}")
        want = env_config.team(team).num_actions
        if actions.get(team) != want or not _is_int(actions.get(team)):
            bad(
                f"num_actions.{team} is {actions.get(team)!r} but its env_config gives the "
                f"{team}s {want} actions"
            )
    if version >= 2:
        try:
            experiment = ExperimentConfig.from_dict(meta.get("experiment"))
        except (TypeError, ValueError) as err:
            bad(f"experiment: {err}")
        if experiment.env != env_config:
            bad("experiment.env differs from env_config")


def read_meta(run_dir: str | Path, step: int | None = None) -> dict[str, Any]:
    """The JSON metadata of the latest (or given) checkpoint, validated. `run_dir` may also be
    a shipped policy's name (`pe_mjx.shipped`)."""
    run_dir = resolve_run(run_dir)
    step = _latest_step(run_dir) if step is None else step
    try:
        with _quiet(), _manager(run_dir, create=False) as mngr:
            meta = mngr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta
    except Exception as err:  # orbax raises many types for a damaged step
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} is unreadable: {_short(err)}"
        ) from None
    check_meta(meta, f"checkpoint {step} in {run_dir}")
    meta["step"] = step
    return meta


def restore_policy_params(
    run_dir: str | Path, team: str
) -> tuple[Any, Any, NetworkConfig, dict[str, Any]]:
    """(network, {"params", "normalizer"}, network config, meta) of one team of a run (a run
    directory or a shipped policy's name)."""
    run_dir = resolve_run(run_dir)
    meta = read_meta(run_dir)
    if team not in TEAMS:
        raise CheckpointError(f"unknown team {team!r}; expected one of {TEAMS}")
    if team not in meta["network_configs"]:
        learned = ", ".join(meta["network_configs"]) or "none"
        raise CheckpointError(
            f"run {run_dir} did not learn a {team} policy (learned teams: {learned})"
        )
    try:
        env_config = EnvConfig.from_dict(meta["env_config"])
        net_config = NetworkConfig.from_dict(meta["network_configs"][team])
    except (TypeError, ValueError) as err:
        raise CheckpointError(f"checkpoint in {run_dir} has an invalid config: {err}") from None
    network = make_network(net_config, int(meta["num_actions"][team]))
    obs = jax.eval_shape(lambda: dummy_obs(env_config, team))  # shapes only: no allocation
    abstract = {
        "params": jax.eval_shape(network.init, jax.random.key(0), obs),
        "normalizer": jax.eval_shape(init_normalizer, obs),
    }
    try:
        with _quiet(), _manager(run_dir, create=False) as mngr:
            restored = mngr.restore(
                meta["step"],
                args=ocp.args.Composite(**{f"policy_{team}": ocp.args.StandardRestore(abstract)}),
            )[f"policy_{team}"]
    except Exception as err:
        raise CheckpointError(
            f"the {team} policy in {run_dir} (step {meta['step']}) cannot be restored: "
            f"{_short(err)}"
        ) from None
    if not all_finite(restored):
        raise CheckpointError(
            f"the {team} policy in {run_dir} (step {meta['step']}) holds non-finite parameters "
            f"(NaN or inf): the run diverged; play an earlier checkpoint or retrain"
        )
    return network, restored, net_config, meta


def all_finite(tree: Any) -> bool:
    """Whether every floating-point leaf of `tree` is finite (no NaN, no inf)."""
    return all(
        bool(np.all(np.isfinite(np.asarray(x))))
        for x in jax.tree.leaves(tree)
        if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)
    )


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


def _restore_across_versions(
    run_dir: Path, step: int, trainer: Trainer, abstract: Any, first_error: Exception
) -> Any:
    """A train state saved by a pe-mjx whose env state had another structure (e.g. a metric was
    added since): the teams (parameters, optimiser and normaliser state), the RNG and the
    counters are restored; the arenas in flight are drawn afresh. Resuming is then exact for
    the learners but not bit-for-bit for the rollouts, and a warning says so.

    The saved leaves are positional (`_flat`): the teams come first and the RNG and counters
    last, so both ends are matched by count and every shape is checked.
    """
    n_teams = len(jax.tree.leaves(abstract.teams))
    tail = [abstract.rng, abstract.iteration, abstract.env_steps]
    try:
        with _quiet(), _manager(run_dir, create=False) as mngr:
            saved = mngr.restore(step, args=ocp.args.Composite(train=ocp.args.StandardRestore()))
        saved = saved.train
        keys = sorted(saved)
        want_teams = jax.tree.leaves(abstract.teams)
        sized = [leaf for leaf in want_teams if math.prod(leaf.shape)]
        team_keys, tail_keys = keys[: len(sized)], keys[-len(tail) :]
        for key, leaf in zip(team_keys, sized, strict=True):
            if tuple(np.shape(saved[key])) != tuple(leaf.shape):
                raise ValueError(f"team leaf {key} has shape {np.shape(saved[key])}")
        for key, leaf in zip(tail_keys, tail, strict=True):
            if tuple(np.shape(saved[key])) != tuple(leaf.shape):
                raise ValueError(f"leaf {key} has shape {np.shape(saved[key])}")
    except Exception as err:
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} cannot be restored: {_short(first_error)} (nor "
            f"its learners alone: {_short(err, 120)})"
        ) from None
    values = iter(np.asarray(saved[k]) for k in team_keys)
    teams = jax.tree.map(
        lambda leaf: next(values) if math.prod(leaf.shape) else np.zeros(leaf.shape, leaf.dtype),
        abstract.teams,
    )
    rng, iteration, env_steps = (np.asarray(saved[k]) for k in tail_keys)
    fresh = jax.device_get(keys_to_data(trainer.init(int(iteration) + trainer.config.seed)))
    print(
        f"pe-mjx: warning: {run_dir} was saved by another pe-mjx version whose arena state "
        f"differs ({len(keys)} saved arrays, {n_teams} of them the learners'): resuming its "
        f"learners, counters and RNG with freshly drawn arenas",
        file=sys.stderr,
    )
    return fresh.replace(teams=teams, rng=rng, iteration=iteration, env_steps=env_steps)


def restore_train_state(run_dir: str | Path, trainer: Trainer) -> TrainState:
    """The full train state of the latest checkpoint, placed with the trainer's shardings.

    `trainer` is built from the run's saved experiment config.
    """
    run_dir = Path(run_dir)
    step = _latest_step(run_dir)
    _require_train_item(run_dir, step)
    template = trainer.abstract_state()
    abstract = jax.eval_shape(keys_to_data, template)
    try:
        with _quiet(), _manager(run_dir, create=False) as mngr:
            restored = mngr.restore(
                step, args=ocp.args.Composite(train=ocp.args.StandardRestore(_flat(abstract)))
            ).train
        restored = _unflat(abstract, jax.tree.map(np.asarray, restored))
    except Exception as err:
        restored = _restore_across_versions(run_dir, step, trainer, abstract, err)
    restored = data_to_keys(template, restored)
    state = jax.tree.map(jnp.asarray, restored)
    env_state = jax.device_put(state.env_state, trainer.batch_sharding)
    teams = jax.device_put(state.teams, trainer.replicated)
    return state.replace(env_state=env_state, teams=teams)
