"""The policy store: reading what `pe-mjx train` wrote (orbax, no pickle), for playing it.

A run directory holds `checkpoints/<iteration>/` with orbax items:
  * `policy_<team>`: per learned team, its parameters and observation statistics (what
    `restore_policy_params` reads, without rebuilding any env);
  * `meta`: JSON with the whole experiment config, the env and network configs it resolved to,
    counters and the format version. Format 1 (before the experiment config) is still read for
    playing its policies; only format 2 runs can be resumed;
  * `train`: the whole train state, which only the trainer reads and writes
    (`pe_mjx.ppo.checkpoint`, which builds on this module's manager and metadata).
Every read validates the metadata against its schema and sane bounds (`check_meta`) before
anything is allocated from it. A latest checkpoint that cannot be read back (truncated or altered
files, invalid metadata, non-finite parameters) is one `DamagedCheckpointError` line naming the
latest intact earlier checkpoint; `fallback=True` (`read_meta`, `restore_policy_params`,
`pe_mjx.load_policy`) reads that one instead, with a warning line, and moves nothing.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple, NoReturn, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from pe_mjx.config import EnvConfig
from pe_mjx.experiment import ExperimentConfig, NetworkConfig
from pe_mjx.names import TEAMS
from pe_mjx.networks import make_network
from pe_mjx.policy import packed
from pe_mjx.policy.inference import dummy_obs, init_normalizer
from pe_mjx.policy.quiet import quiet_logs
from pe_mjx.policy.shipped import resolve_run, retired_note

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


class DamagedCheckpointError(CheckpointError):
    """One checkpoint of a run cannot be read back (a truncated or altered file, metadata that
    fails its checks, non-finite parameters), where an earlier one of the same run may be
    intact. The readers that meet it at the latest checkpoint name the latest intact one and,
    with `fallback=True`, use it."""


DAMAGED_DIR = "damaged-checkpoints"
"""Where `--resume-intact` (`pe_mjx.ppo.checkpoint.restore_train_state(fallback=True)`) moves
damaged checkpoints, under the run directory: nothing is deleted."""


def one_line(text: str, limit: int = 300) -> str:
    """`text` with its whitespace (newlines of library messages too) collapsed, cut at `limit`."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit] + " ..."


def intact_hint(run_dir: Path, step: int) -> str:
    """What a message about a damaged latest checkpoint says about the intact `step`."""
    return (
        f"checkpoint {step} is the latest intact one: use it with `pe-mjx train --resume "
        f"{run_dir} --resume-intact` or fallback=True in Python"
    )


def warn_fallback(err: Exception, step: int, doing: str) -> None:
    """The one warning line of a reader that falls back to the intact checkpoint `step`."""
    print(f"pe-mjx: warning: {err}; {doing} checkpoint {step} instead", file=sys.stderr)


_ARRAY_READ_FAILED = "Encountered error while reading array"
"""How orbax words a failed array read: its message goes on to print the whole TensorStore spec,
while the exception it chains to names the array and what is wrong with its bytes."""


def short_error(err: Exception, limit: int = 300) -> str:
    """`err` in one line: its type and message, whitespace collapsed, cut at `limit`. A failed
    array read is told by its cause (e.g. `OUT_OF_RANGE: Error reading "params...kernel/0.0"
    ...: Requested byte range ... is not valid`), not by orbax's echo of the store's spec."""
    cause = err.__cause__ or err.__context__
    if str(err).startswith(_ARRAY_READ_FAILED) and cause is not None:
        err = cause
    return one_line(f"{type(err).__name__}: {err}", limit)


RESUMABLE_COPY = "resumable_copy"
"""The metadata key of a resumable copy's checkpoint (`pe_mjx.ppo.checkpoint`): learners only,
no policy items to play."""


def manager(run_dir: Path, create: bool) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(max_to_keep=MAX_TO_KEEP, create=create)
    return ocp.CheckpointManager(
        (run_dir / CHECKPOINT_DIR).absolute(),
        options=options,
        item_names=("train", "meta", *(f"policy_{t}" for t in TEAMS)),
    )


def latest_step(run_dir: Path) -> int:
    if not run_dir.exists():
        raise CheckpointError(
            retired_note(run_dir) or f"no run at {run_dir}: the directory does not exist"
        )
    if packed.is_packed(run_dir):
        raise CheckpointError(
            f"{run_dir} is a packed policy ({packed.PACKED_FILE}): it plays, but holds no "
            f"checkpoint to resume or ship from"
        )
    if not (run_dir / CHECKPOINT_DIR).is_dir():
        raise CheckpointError(f"{run_dir} holds no checkpoints (no {CHECKPOINT_DIR}/ directory)")
    try:
        with quiet_logs(), manager(run_dir, create=False) as mngr:
            step = mngr.latest_step()
    except Exception as err:  # an unreadable directory, a damaged step name
        raise CheckpointError(
            f"{run_dir}: cannot list its checkpoints: {short_error(err)}"
        ) from None
    if step is None:
        raise CheckpointError(
            f"{run_dir} holds no complete checkpoint (a run stopped during its first save?); "
            f"`pe-mjx train --out {run_dir}` starts it afresh"
        )
    return step


def all_steps(run_dir: Path) -> list[int]:
    """The run's complete checkpoints, newest first (`latest_step` has checked the directory)."""
    try:
        with quiet_logs(), manager(run_dir, create=False) as mngr:
            return sorted(mngr.all_steps(), reverse=True)
    except Exception as err:
        raise CheckpointError(
            f"{run_dir}: cannot list its checkpoints: {short_error(err)}"
        ) from None


T = TypeVar("T")


def earlier_intact(run_dir: Path, damaged: int, read: Callable[[int], T]) -> tuple[int, T] | None:
    """(step, what `read(step)` returned) of the newest checkpoint before `damaged` that `read`
    reads without a `CheckpointError`; None if there is none."""
    for step in all_steps(run_dir):
        if step >= damaged:
            continue
        try:
            return step, read(step)
        except CheckpointError:
            continue
    return None


def with_fallback(
    run_dir: Path, step: int | None, read: Callable[[int], T], fallback: bool, doing: str
) -> T:
    """`read(step)`, the latest step when `step` is None. When the latest is damaged, a
    `DamagedCheckpointError` that names the latest intact earlier one, or, with `fallback`,
    a warning line and that one's reading."""
    if step is not None:
        return read(step)
    try:
        return read(latest_step(run_dir))
    except DamagedCheckpointError as err:
        found = intact_instead(run_dir, err, read, fallback)
        warn_fallback(err, found[0], doing)
        return found[1]


def intact_instead(
    run_dir: Path,
    err: Exception,
    read: Callable[[int], T],
    fallback: bool,
    either: str = "is intact",
) -> tuple[int, T]:
    """After the latest checkpoint failed with `err`: (step, `read(step)`) of the latest intact
    earlier one when `fallback`; otherwise, or when there is none, the error that says so."""
    latest = latest_step(run_dir)
    if not any(s < latest for s in all_steps(run_dir)):
        raise err  # the run's only checkpoint
    found = earlier_intact(run_dir, latest, read)
    if found is None:
        raise DamagedCheckpointError(
            f"{err}; no earlier checkpoint of {run_dir} {either} either"
        ) from None
    if not fallback:
        raise DamagedCheckpointError(f"{err}; {intact_hint(run_dir, found[0])}") from None
    return found


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def check_meta(meta: Any, where: str) -> None:
    """Checks a checkpoint's metadata against its schema and sane bounds before anything is
    built from it; raises `CheckpointError` naming the first bad field."""

    def bad(message: str) -> NoReturn:
        raise DamagedCheckpointError(f"{where} has invalid metadata: {message}")

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


def read_meta(
    run_dir: str | Path, step: int | None = None, fallback: bool = False
) -> dict[str, Any]:
    """The JSON metadata of the latest (or given) checkpoint, validated. `run_dir` may also be
    a shipped policy's name (`pe_mjx.policy.shipped`). When the latest is damaged: a
    `DamagedCheckpointError` naming the latest intact one, or, with `fallback`, that one's."""
    run_dir = resolve_run(run_dir)
    if packed.is_packed(run_dir):
        meta = _read_packed(run_dir)[0]
        if step is not None and step != meta["step"]:
            raise CheckpointError(
                f"{run_dir} is a packed policy of step {meta['step']}, not {step}"
            )
        return meta
    return with_fallback(
        run_dir, step, lambda s: _read_meta(run_dir, s), fallback, "reading the metadata of"
    )


def _read_packed(run_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(validated metadata, team -> policy state dict) of a packed policy directory."""
    try:
        meta, policies = packed.read(run_dir)
    except packed.PackedPolicyError as err:
        raise DamagedCheckpointError(str(err)) from None
    where = f"the packed policy {run_dir / packed.PACKED_FILE}"
    check_meta(meta, where)
    if not _is_int(meta.get("step")) or meta["step"] < 0:
        raise DamagedCheckpointError(f"{where} has invalid metadata: step is missing")
    return meta, policies


def _read_meta(run_dir: Path, step: int) -> dict[str, Any]:
    try:
        with quiet_logs(), manager(run_dir, create=False) as mngr:
            meta = mngr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta
    except Exception as err:  # orbax raises many types for a damaged step
        raise DamagedCheckpointError(
            f"checkpoint {step} in {run_dir} is unreadable: {short_error(err)}"
        ) from None
    check_meta(meta, f"checkpoint {step} in {run_dir}")
    meta["step"] = step
    return meta


def everywhere(abstract: Any) -> Any:
    """Restore targets (`jax.ShapeDtypeStruct`s) for the shapes and dtypes of `abstract`, each
    replicated over every device (every process's, in a group). Orbax otherwise restores onto
    the devices named in the checkpoint's metadata, which another number of processes or devices
    does not have."""
    sharding = jax.sharding.NamedSharding(
        jax.sharding.Mesh(np.array(jax.devices()), ("devices",)), jax.sharding.PartitionSpec()
    )
    return jax.tree.map(
        lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), abstract
    )


def _key_name(key: Any) -> str:
    """A path entry's name, alike for dicts, attributes and sequences (orbax stores dicts)."""
    for field in ("key", "name", "idx"):
        if hasattr(key, field):
            return str(getattr(key, field))
    return str(key)


def _shapes(tree: Any) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Each leaf of `tree` (arrays, shape structs or orbax's array metadata) by its dotted path."""
    return {
        ".".join(_key_name(k) for k in path): (tuple(x.shape), np.dtype(x.dtype))
        for path, x in jax.tree_util.tree_leaves_with_path(tree)
    }


def shape_mismatch(have: Any, want: Any) -> str | None:
    """The first difference between two trees of arrays (or shape structs, or orbax's array
    metadata) in their leaves' paths, shapes and dtypes, in words; None when they agree."""
    found, wanted = _shapes(have), _shapes(want)
    for name in sorted(wanted.keys() | found.keys()):
        if name not in found:
            return f"lacks the array {name}"
        if name not in wanted:
            return f"holds an array {name} that is not expected"
        (shape, dtype), (want_shape, want_dtype) = found[name], wanted[name]
        if shape != want_shape or dtype != want_dtype:
            return f"{name} is {dtype}{list(shape)} where {want_dtype}{list(want_shape)} is needed"
    return None


def _check_stored_shapes(item_dir: Path, abstract: Any, where: str) -> None:
    """Checks the arrays an orbax item declares (its metadata only: no array is read) against
    the shapes and dtypes its config implies, so that a checkpoint whose config and arrays
    disagree is one clear error, before orbax allocates for it or starts reading."""
    try:
        with quiet_logs():
            stored = ocp.StandardCheckpointHandler().metadata(item_dir.absolute())
    except Exception as err:  # orbax raises many types for a damaged item
        raise DamagedCheckpointError(f"{where} cannot be restored: {short_error(err)}") from None
    problem = shape_mismatch(stored, abstract)
    if problem is not None:
        raise DamagedCheckpointError(f"{where} does not match its network config: it {problem}")


class RestoredPolicy(NamedTuple):
    """One team's learned policy as a run stored it, with the configs parsed once."""

    network: Any  # the flax module
    variables: Any  # {"params", "normalizer"}
    net_config: NetworkConfig
    env_config: EnvConfig  # the scene it will play: the one asked for, else its training scene
    trained: EnvConfig  # the scene it was trained in
    meta: dict[str, Any]


def restore_policy_params(
    run_dir: str | Path,
    team: str,
    scene: EnvConfig | None = None,
    fallback: bool = False,
    step: int | None = None,
) -> RestoredPolicy:
    """One team of a run (a run directory or a shipped policy's name), for playing in `scene`
    (default: the scene it was trained in), whose action count for `team` must be the run's.

    When the latest checkpoint is damaged (`DamagedCheckpointError`), the error names the latest
    intact one; with `fallback` that one is played instead, with a warning line on stderr.
    `step` picks a checkpoint of a run (default: the latest; a packed policy has one)."""
    run_dir = resolve_run(run_dir)
    if team not in TEAMS:
        raise CheckpointError(f"unknown team {team!r}; expected one of {TEAMS}")
    if packed.is_packed(run_dir):
        restored = _restore_policy(run_dir, team, scene, None)
        if step is not None and step != restored.meta["step"]:
            raise CheckpointError(f"{run_dir} is a packed policy of step {restored.meta['step']}")
        return restored
    return with_fallback(
        run_dir, step, lambda s: _restore_policy(run_dir, team, scene, s), fallback, "playing"
    )


def _restore_policy(
    run_dir: Path, team: str, scene: EnvConfig | None, step: int | None
) -> RestoredPolicy:
    """One team's policy from checkpoint `step` of a run, or (`step` None) a packed policy."""
    state = None
    if step is None:
        meta, state = _read_packed(run_dir)
    else:
        meta = _read_meta(run_dir, step)
    if team not in TEAMS:
        raise CheckpointError(f"unknown team {team!r}; expected one of {TEAMS}")
    if meta.get(RESUMABLE_COPY):
        raise CheckpointError(
            f"checkpoint {step} in {run_dir} is a resumable copy (learners only, no policies to "
            f"play): resume it (`pe-mjx train --resume`) to its next checkpoint, or play the run"
        )
    if team not in meta["network_configs"]:
        learned = ", ".join(meta["network_configs"]) or "none"
        raise CheckpointError(
            f"run {run_dir} did not learn a {team} policy (learned teams: {learned})"
        )
    try:
        trained = EnvConfig.from_dict(meta["env_config"])
        net_config = NetworkConfig.from_dict(meta["network_configs"][team])
    except (TypeError, ValueError) as err:
        raise CheckpointError(f"checkpoint in {run_dir} has an invalid config: {err}") from None
    scene = trained if scene is None else scene
    have, want = int(meta["num_actions"][team]), scene.team(team).num_actions
    if have != want:
        raise CheckpointError(
            f"the {team} policy in {run_dir} has {have} actions but this scene's {team}s "
            f"have {want}"
        )
    network = make_network(net_config, have)
    obs = jax.eval_shape(lambda: dummy_obs(trained, team))  # shapes only: no allocation
    abstract = everywhere(
        {
            "params": jax.eval_shape(network.init, jax.random.key(0), obs),
            "normalizer": jax.eval_shape(init_normalizer, obs),
        }
    )
    where = f"the {team} policy in {run_dir} (step {meta['step']})"
    if state is not None:
        restored = _restore_packed(state.get(team), abstract, where)
    else:
        restored = _restore_item(run_dir, team, meta["step"], abstract, where)
    if not all_finite(restored):
        raise DamagedCheckpointError(
            f"{where} holds non-finite parameters (NaN or inf): the run diverged; play an "
            f"earlier checkpoint or retrain"
        )
    return RestoredPolicy(network, restored, net_config, scene, trained, meta)


def _restore_item(run_dir: Path, team: str, step: int, abstract: Any, where: str) -> Any:
    """The team's orbax item of checkpoint `step`, its declared shapes checked first."""
    _check_stored_shapes(run_dir / CHECKPOINT_DIR / str(step) / f"policy_{team}", abstract, where)
    try:
        with quiet_logs(), manager(run_dir, create=False) as mngr:
            return mngr.restore(
                step,
                args=ocp.args.Composite(**{f"policy_{team}": ocp.args.StandardRestore(abstract)}),
            )[f"policy_{team}"]
    except Exception as err:
        raise DamagedCheckpointError(f"{where} cannot be restored: {short_error(err)}") from None


def _restore_packed(state: Any, abstract: Any, where: str) -> Any:
    """The team's arrays of a packed policy, checked against `abstract` and placed like it."""
    if state is None:
        raise DamagedCheckpointError(f"{where} is missing from its packed file")
    try:
        restored = packed.restore(state, abstract)
    except packed.PackedPolicyError as err:
        raise DamagedCheckpointError(f"{where}: {err}") from None
    problem = shape_mismatch(restored, abstract)
    if problem is not None:
        raise DamagedCheckpointError(f"{where} does not match its network config: it {problem}")
    return jax.tree.map(lambda x, a: jax.device_put(x, a.sharding), restored, abstract)


def all_finite(tree: Any) -> bool:
    """Whether every floating-point leaf of `tree` is finite (no NaN, no inf)."""
    return all(
        bool(np.all(np.isfinite(np.asarray(x))))
        for x in jax.tree.leaves(tree)
        if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating)
    )
