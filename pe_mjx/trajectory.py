"""Recorded episodes as `.npz` files: the format the evaluator writes and the viewer replays.

One file holds B arenas of one scene played for T frames (frame 0 is the reset state):

===============  =====================  ==========================================================
key              shape, dtype           meaning
===============  =====================  ==========================================================
``format``       [] int                 `FORMAT_VERSION`
``config_json``  [] str                 the `EnvConfig` as JSON (`EnvConfig.to_json`)
``poses``        [T, B, N, 3] float     x, y, yaw of the N = P + E agents, pursuers first
``active``       [T, B, N] bool         False once an agent is incapacitated
``obstacles``    [B, K, 3] float        x, y, radius (obstacles never move)
``cause``        [T, B, N] int          optional: `env.World.cause` codes (0 while active)
``meta_json``    [] str                 optional: a JSON object (policies, seed, ...)
===============  =====================  ==========================================================

Files are read with ``np.load(allow_pickle=False)``: plain arrays only, never pickles. Every
array's shape and dtype is checked on save and on load, with errors that name the file and key.
"""

from __future__ import annotations

import dataclasses
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from pe_mjx.config import EnvConfig

FORMAT_VERSION = 1
NUM_CAUSES = 6  # env.ACTIVE .. env.OPPONENT
REQUIRED_KEYS = ("format", "config_json", "poses", "active", "obstacles")
OPTIONAL_KEYS = ("cause", "meta_json")


class TrajectoryError(ValueError):
    """A trajectory file or array that does not follow the format."""


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """B arenas of one scene over T frames (numpy arrays; see the module docstring)."""

    config: EnvConfig
    poses: np.ndarray
    """float32 [T, B, N, 3]: x, y, yaw."""
    active: np.ndarray
    """bool [T, B, N]."""
    obstacles: np.ndarray
    """float32 [B, K, 3]: x, y, radius."""
    cause: np.ndarray | None = None
    """int32 [T, B, N] incapacitation causes, or None when not recorded."""
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)
    """Free-form JSON metadata (policy names, seed, ...)."""

    def __post_init__(self) -> None:
        validate(self)

    @property
    def num_frames(self) -> int:
        return int(self.poses.shape[0])

    @property
    def num_arenas(self) -> int:
        return int(self.poses.shape[1])

    def causes(self) -> np.ndarray:
        """int32 [T, B, N]: the recorded causes, or 0 / -1 (active / unknown) when absent."""
        if self.cause is not None:
            return self.cause
        return np.where(self.active, 0, -1).astype(np.int32)

    def select(self, arenas: int) -> Trajectory:
        """The first `arenas` arenas only."""
        b = max(1, min(arenas, self.num_arenas))
        return Trajectory(
            config=self.config,
            poses=self.poses[:, :b],
            active=self.active[:, :b],
            obstacles=self.obstacles[:b],
            cause=None if self.cause is None else self.cause[:, :b],
            meta=self.meta,
        )


def _fail(where: str, key: str, message: str) -> None:
    raise TrajectoryError(f"{where}: {key} {message}")


def _check_array(
    where: str, key: str, x: Any, shape: tuple[int | None, ...], kind: str
) -> np.ndarray:
    """Checks rank, known dims and dtype kind ("f" float, "b" bool, "i" integer)."""
    if not isinstance(x, np.ndarray):
        _fail(where, key, f"must be a numpy array, got {type(x).__name__}")
    fits = x.ndim == len(shape) and all(
        s is None or s == d for s, d in zip(shape, x.shape, strict=True)
    )
    if not fits:
        want = "[" + ", ".join("?" if s is None else str(s) for s in shape) + "]"
        _fail(where, key, f"has shape {list(x.shape)}, expected {want}")
    ok = {
        "f": np.issubdtype(x.dtype, np.floating),
        "b": x.dtype == np.bool_,
        "i": np.issubdtype(x.dtype, np.integer),
    }[kind]
    if not ok:
        names = {"f": "a float", "b": "bool", "i": "an integer"}
        _fail(where, key, f"has dtype {x.dtype}, expected {names[kind]} dtype")
    return x


def validate(traj: Trajectory, where: str = "trajectory") -> None:
    """Raises TrajectoryError unless every array fits the config and the others."""
    _validate(where, traj.config, traj.poses, traj.active, traj.obstacles, traj.cause, traj.meta)


def _validate(
    where: str,
    config: Any,
    poses: Any,
    active: Any,
    obstacles: Any,
    cause: Any,
    meta: Any,
) -> None:
    if not isinstance(config, EnvConfig):
        _fail(where, "config", f"must be an EnvConfig, got {type(config).__name__}")
    n, k = config.num_agents, config.arena.num_obstacles
    _check_array(where, "poses", poses, (None, None, n, 3), "f")
    t, b = poses.shape[:2]
    if t < 1 or b < 1:
        _fail(where, "poses", f"must hold at least one frame and one arena, got shape {[t, b]}")
    if not np.all(np.isfinite(poses)):
        _fail(where, "poses", "holds NaN or infinite values")
    _check_array(where, "active", active, (t, b, n), "b")
    _check_array(where, "obstacles", obstacles, (b, k, 3), "f")
    if not np.all(np.isfinite(obstacles)):
        _fail(where, "obstacles", "holds NaN or infinite values")
    if cause is not None:
        _check_array(where, "cause", cause, (t, b, n), "i")
        if cause.size and (cause.min() < 0 or cause.max() >= NUM_CAUSES):
            _fail(where, "cause", f"must hold codes 0..{NUM_CAUSES - 1}")
        if np.any((cause == 0) != active):
            _fail(where, "cause", "must be 0 exactly where active is True")
    if not isinstance(meta, dict):
        _fail(where, "meta", f"must be a dict, got {type(meta).__name__}")


def save(path: str | Path, traj: Trajectory, overwrite: bool = False) -> Path:
    """Writes `traj` to `path` (.npz, compressed), atomically; refuses to overwrite by default."""
    path = Path(path)
    if path.suffix != ".npz":
        raise TrajectoryError(f"{path}: a trajectory file must end in .npz")
    if path.exists() and not overwrite:
        raise TrajectoryError(f"{path} exists; refusing to overwrite it")
    validate(traj, str(path))
    arrays: dict[str, np.ndarray] = {
        "format": np.asarray(FORMAT_VERSION, dtype=np.int32),
        "config_json": np.asarray(traj.config.to_json()),
        "poses": np.asarray(traj.poses, dtype=np.float32),
        "active": np.asarray(traj.active, dtype=bool),
        "obstacles": np.asarray(traj.obstacles, dtype=np.float32),
    }
    if traj.cause is not None:
        arrays["cause"] = np.asarray(traj.cause, dtype=np.int8)
    if traj.meta:
        arrays["meta_json"] = np.asarray(json.dumps(traj.meta, sort_keys=True))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    tmp.replace(path)
    return path


def _json_scalar(where: str, key: str, x: np.ndarray) -> Any:
    if x.ndim != 0 or x.dtype.kind != "U":
        _fail(where, key, f"must be a string scalar, got dtype {x.dtype} shape {list(x.shape)}")
    try:
        return json.loads(str(x))
    except json.JSONDecodeError as err:
        _fail(where, key, f"is not valid JSON: {err}")


def load(path: str | Path) -> Trajectory:
    """Reads and validates a trajectory file; every problem raises TrajectoryError."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise TrajectoryError(f"{where}: no such file")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise TrajectoryError(f"{where}: not a readable .npz file ({err})") from None
    missing = [key for key in REQUIRED_KEYS if key not in arrays]
    if missing:
        raise TrajectoryError(f"{where}: missing keys {missing} (has {sorted(arrays)})")
    unknown = sorted(set(arrays) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise TrajectoryError(f"{where}: unknown keys {unknown}")
    version = arrays["format"]
    if version.shape != () or not np.issubdtype(version.dtype, np.integer):
        _fail(where, "format", "must be an integer scalar")
    if int(version) != FORMAT_VERSION:
        _fail(where, "format", f"is {int(version)}; this pe-mjx reads {FORMAT_VERSION}")
    try:
        config = EnvConfig.from_dict(_json_scalar(where, "config_json", arrays["config_json"]))
    except ValueError as err:
        if isinstance(err, TrajectoryError):
            raise
        raise TrajectoryError(f"{where}: config_json: {err}") from None
    meta = {}
    if "meta_json" in arrays:
        meta = _json_scalar(where, "meta_json", arrays["meta_json"])
        if not isinstance(meta, dict):
            _fail(where, "meta_json", "must hold a JSON object")
    cause = arrays.get("cause")
    _validate(where, config, arrays["poses"], arrays["active"], arrays["obstacles"], cause, meta)
    return Trajectory(
        config=config,
        poses=arrays["poses"].astype(np.float32),
        active=arrays["active"],
        obstacles=arrays["obstacles"].astype(np.float32),
        cause=None if cause is None else cause.astype(np.int32),
        meta=meta,
    )


def from_episodes(
    config: EnvConfig, record: dict[str, Any], final_state: Any, meta: dict | None = None
) -> Trajectory:
    """The trajectory of `episodes.play_episodes(..., record=True)`.

    Args:
      config: the env's config.
      record: the recorded dict: poses [T, B, N, 3], active [T, B, N].
      final_state: the batched final `env.State` [B]; gives the obstacles and, since an agent's
        cause never changes once set, every frame's cause (its final cause wherever it is inactive).
      meta: optional JSON-serialisable metadata.
    """
    poses = np.asarray(record["poses"], dtype=np.float32)
    active = np.asarray(record["active"], dtype=bool)
    final_cause = np.asarray(final_state.world.cause, dtype=np.int32)
    cause = np.where(active, 0, final_cause[None]).astype(np.int32)
    return Trajectory(
        config=config,
        poses=poses,
        active=active,
        obstacles=np.asarray(final_state.world.obstacles, dtype=np.float32),
        cause=cause,
        meta=dict(meta or {}),
    )


__all__ = ["FORMAT_VERSION", "Trajectory", "TrajectoryError", "from_episodes", "load", "save"]
