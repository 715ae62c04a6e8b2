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

Files are read with ``np.load(allow_pickle=False)``: plain arrays only, never pickles. On load,
every member's ``.npy`` header (dtype, shape, size) is checked against the schema, the bounds below
and the zip directory *before* any array is read, so a damaged or crafted file is one
`TrajectoryError` that names the file and key, never a MemoryError. Every array's shape and dtype is
checked again on save and on load, and so are the game's rules: an incapacitated agent never moves
and never comes back, and its cause never changes.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from pe_mjx.config import EnvConfig
from pe_mjx.names import NUM_CAUSES, PARK_DISTANCE

FORMAT_VERSION = 1
REQUIRED_KEYS = ("format", "config_json", "poses", "active", "obstacles")
OPTIONAL_KEYS = ("cause", "meta_json")

MAX_FRAMES = 1_000_000
"""T at most (an episode of the longest preset has a few thousand frames)."""
MAX_ARENAS = 65_536
"""B at most."""
MAX_ARRAY_BYTES = 2 << 30
"""Bytes of one array at most, as its header declares (2 GiB)."""
MAX_JSON_CHARS = 1 << 20
"""Characters of ``config_json`` and ``meta_json`` at most."""
_MEMBER_RANK = {
    "format": 0,
    "config_json": 0,
    "meta_json": 0,
    "poses": 4,
    "active": 3,
    "obstacles": 3,
    "cause": 3,
}
_MEMBER_KINDS = {
    "format": "iu",
    "config_json": "U",
    "meta_json": "U",
    "poses": "f",
    "active": "b",
    "obstacles": "f",
    "cause": "iu",
}


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
    # Every position lies in the arena, or where absent agents and obstacles wait (beyond it):
    # a crafted position far outside drew an empty arena without a word.
    reach = _reach(config)
    for key, xy in (("poses", poses[..., :2]), ("obstacles", obstacles[..., :2])):
        far = np.abs(xy).max(initial=0.0)
        if far > reach:
            radius = config.arena.radius
            _fail(
                where,
                key,
                f"holds a position {far:.3g} m from the centre, beyond the {reach:g} m that an "
                f"arena of radius {radius:g} m can record",
            )
    if obstacles.size and obstacles[..., 2].min() < 0:
        _fail(where, "obstacles", "holds a negative radius")
    if cause is not None:
        _check_array(where, "cause", cause, (t, b, n), "i")
        if cause.size and (cause.min() < 0 or cause.max() >= NUM_CAUSES):
            _fail(where, "cause", f"must hold codes 0..{NUM_CAUSES - 1}")
        if np.any((cause == 0) != active):
            _fail(where, "cause", "must be 0 exactly where active is True")
    _check_rules(where, poses, active, cause)
    if not isinstance(meta, dict):
        _fail(where, "meta", f"must be a dict, got {type(meta).__name__}")


def _reach(config: EnvConfig) -> float:
    """The farthest |x| or |y| a recorded position may have: the arena, or the row where the env
    parks absent agents and obstacles (`PARK_DISTANCE` radii out, one metre apart)."""
    radius = config.arena.radius
    return (PARK_DISTANCE + 1) * radius + config.num_agents + config.arena.num_obstacles


def _first(mask: np.ndarray) -> str:
    """'frame t, arena b, agent i' of the first True of a [T, B, N] mask (frames from 1)."""
    t, b, i = (int(x) for x in np.argwhere(mask)[0])
    return f"frame {t + 1}, arena {b}, agent {i}"


def _check_rules(where: str, poses: np.ndarray, active: np.ndarray, cause: Any) -> None:
    """The game's rules (as `env.step` plays them): an incapacitated agent stays incapacitated,
    keeps its pose exactly, and keeps its cause."""
    was_down = ~active[:-1]
    back = was_down & active[1:]
    if np.any(back):
        _fail(where, "active", f"breaks the rules: a downed agent is active again ({_first(back)})")
    moved = was_down & np.any(poses[1:] != poses[:-1], axis=-1)
    if np.any(moved):
        _fail(where, "poses", f"break the rules: a downed agent moves ({_first(moved)})")
    if cause is not None:
        changed = was_down & (cause[1:] != cause[:-1])
        if np.any(changed):
            _fail(
                where,
                "cause",
                f"breaks the rules: a downed agent's cause changes ({_first(changed)})",
            )


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
    except RecursionError:  # `[[[[...` ten thousand deep: a crafted file
        _fail(where, key, "is JSON nested too deeply to read")


def _brief(err: BaseException) -> str:
    """A library's error message on one short line (zipfile quotes raw bytes)."""
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 160 else text[:157] + "..."


@dataclasses.dataclass(frozen=True)
class _Member:
    """What a member's .npy header declares."""

    shape: tuple[int, ...]
    dtype: np.dtype


def _read_header(where: str, key: str, zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> _Member:
    """Reads and checks one member's .npy header (dtype kind, rank, size against the zip entry);
    reads no array data."""
    fmt = np.lib.format
    try:
        with zf.open(info) as f:
            version = fmt.read_magic(f)
            if version == (1, 0):
                shape, _, dtype = fmt.read_array_header_1_0(f)
            elif version in ((2, 0), (3, 0)):
                shape, _, dtype = fmt.read_array_header_2_0(f)
            else:
                raise ValueError(f"unsupported .npy version {version}")
            offset = f.tell()
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, SyntaxError) as err:
        _fail(where, key, f"is not a readable .npy array ({_brief(err)})")
    if dtype.hasobject:
        _fail(where, key, "holds Python objects (pickles are never loaded)")
    if dtype.kind not in _MEMBER_KINDS[key] or dtype.subdtype is not None or dtype.names:
        _fail(where, key, f"has dtype {dtype}, which this format does not use here")
    if len(shape) != _MEMBER_RANK[key]:
        _fail(where, key, f"has {len(shape)} dimensions, expected {_MEMBER_RANK[key]}")
    if any(not isinstance(d, int) or d < 0 for d in shape):
        _fail(where, key, f"has an invalid shape {list(shape)}")
    if key.endswith("_json") and dtype.itemsize > 4 * MAX_JSON_CHARS:
        _fail(where, key, f"is longer than {MAX_JSON_CHARS:,} characters")
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        _fail(
            where,
            key,
            f"declares {nbytes:,} bytes (shape {list(shape)}), more than the "
            f"{MAX_ARRAY_BYTES:,} a trajectory array may hold: a damaged or crafted file",
        )
    # Deflate expands at most ~1032-fold: a larger claim is a crafted entry, refused before the
    # read allocates what it claims.
    limit = (
        info.compress_size
        if info.compress_type == zipfile.ZIP_STORED
        else 1100 * info.compress_size
    )
    if info.file_size > limit + 4096:
        _fail(
            where,
            key,
            f"is damaged: its zip entry claims {info.file_size:,} bytes from "
            f"{info.compress_size:,} compressed",
        )
    if info.file_size != offset + nbytes:
        _fail(
            where,
            key,
            f"is damaged: its header declares {nbytes:,} bytes of data but the zip entry holds "
            f"{max(info.file_size - offset, 0):,}",
        )
    return _Member(shape=tuple(shape), dtype=dtype)


def _read_headers(where: str, zf: zipfile.ZipFile) -> dict[str, _Member]:
    """Every member's header, checked against the schema and against each other."""
    members: dict[str, _Member] = {}
    infos: dict[str, zipfile.ZipInfo] = {}
    for info in zf.infolist():
        key = info.filename.removesuffix(".npy")
        if key in infos or key not in _MEMBER_RANK:
            if key in infos:
                raise TrajectoryError(f"{where}: key {key!r} appears twice")
            known = sorted(_MEMBER_RANK)
            raise TrajectoryError(f"{where}: unknown keys [{key!r}] (known: {known})")
        infos[key] = info
    missing = [key for key in REQUIRED_KEYS if key not in infos]
    if missing:
        raise TrajectoryError(f"{where}: missing keys {missing} (has {sorted(infos)})")
    for key, info in infos.items():
        members[key] = _read_header(where, key, zf, info)
    t, b = members["poses"].shape[:2]
    if not 1 <= t <= MAX_FRAMES:
        _fail(where, "poses", f"holds {t} frames; expected 1..{MAX_FRAMES:,}")
    if not 1 <= b <= MAX_ARENAS:
        _fail(where, "poses", f"holds {b} arenas; expected 1..{MAX_ARENAS:,}")
    return members


def load(path: str | Path) -> Trajectory:
    """Reads and validates a trajectory file; every problem raises TrajectoryError.

    The headers of all members are checked (schema, bounds, sizes) before any array is read; the
    arrays are then checked against the scene's config and against the game's rules.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise TrajectoryError(f"{where}: no such file")
    if not path.is_file():
        raise TrajectoryError(f"{where}: not a file")
    try:
        with zipfile.ZipFile(path) as zf:
            members = _read_headers(where, zf)
    except (OSError, zipfile.BadZipFile, EOFError, ValueError) as err:
        if isinstance(err, TrajectoryError):
            raise
        raise TrajectoryError(f"{where}: not a readable .npz file ({_brief(err)})") from None
    small = {key: m for key, m in members.items() if key in ("format", "config_json", "meta_json")}
    arrays = _read_arrays(where, path, small)
    version = arrays["format"]
    if int(version) != FORMAT_VERSION:
        _fail(where, "format", f"is {int(version)}; this pe-mjx reads {FORMAT_VERSION}")
    try:
        config = EnvConfig.from_dict(_json_scalar(where, "config_json", arrays["config_json"]))
    except (ValueError, TypeError) as err:
        if isinstance(err, TrajectoryError):
            raise
        raise TrajectoryError(f"{where}: config_json: {err}") from None
    meta = {}
    if "meta_json" in arrays:
        meta = _json_scalar(where, "meta_json", arrays["meta_json"])
        if not isinstance(meta, dict):
            _fail(where, "meta_json", "must hold a JSON object")
    # The config fixes N and K: check the declared shapes before reading the big arrays.
    n, k = config.num_agents, config.arena.num_obstacles
    t, b = members["poses"].shape[:2]
    expected = {"poses": (t, b, n, 3), "active": (t, b, n), "obstacles": (b, k, 3)}
    expected["cause"] = (t, b, n)
    for key, shape in expected.items():
        if key in members and members[key].shape != shape:
            _fail(where, key, f"has shape {list(members[key].shape)}, expected {list(shape)}")
    arrays.update(_read_arrays(where, path, {k: m for k, m in members.items() if k in expected}))
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


def _read_arrays(where: str, path: Path, members: dict[str, _Member]) -> dict[str, np.ndarray]:
    """Reads the given (already checked) members; a read error is a TrajectoryError."""
    out = {}
    try:
        with np.load(path, allow_pickle=False) as data:
            for key, member in members.items():
                out[key] = data[key]
                if out[key].shape != member.shape or out[key].dtype != member.dtype:
                    _fail(where, key, "changed while it was read")
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        if isinstance(err, TrajectoryError):
            raise
        raise TrajectoryError(f"{where}: not a readable .npz file ({_brief(err)})") from None
    return out


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
