"""Runs a policy file written by `pe-mjx export`, with jax and numpy only (copy it anywhere).

This module imports nothing from pe_mjx, flax, brax or the training code, so it can be copied on
its own to a robot's computer that has `jax` (with `flatbuffers`, which `jax.export` needs to
read the file) and `numpy`::

    from export_loader import load
    policy = load("pursuer.jaxexport")
    actions = policy(obs)                 # int32 [A], greedy over the masked logits
    v, omega = policy.commands(obs)       # m/s and rad/s per robot

The file is a zip archive of two members:

* ``policy.stablehlo``: the `jax.export` serialisation (StableHLO bytecode plus its calling
  convention) of ``(own, teammates, opponents, obstacles, teammate_mask, opponent_mask,
  obstacle_mask, action_mask) -> (actions int32 [A], logits float32 [A, n_actions])``: the
  observation normaliser and the network parameters are constants inside it, and the logits of
  masked actions are -1e9;
* ``meta.json``: the format tag and version, the team, the inputs' names, shapes and dtypes, the
  team's action table (the (v, omega) of each action index), the game config and the run it came
  from.

The shapes are fixed when the file is written (a team size, the other team's size, an obstacle
count). Observations with fewer agents or entities are padded up to them with masked entries,
which the networks ignore (padded entities are zeroed and masked out of attention and means), and
the extra rows are dropped from the outputs; more than the exported counts is an error.

Every file is checked before anything is built from it, and anything malformed (not a zip, a
truncated or altered byte, a missing member, wrong metadata, inputs that disagree with the
program) is a `ValueError` naming the file and what is wrong. No member is read past the size its
compressed bytes in the file can hold (zip's own CRC-32 then vouches for every byte), and the
input shapes are bounded, so a damaged or crafted file cannot make the loader allocate much more
than its own size. Eager calls refuse observations with NaN or inf and an action mask with no
valid action for some agent (`ValueError`); under `jax.jit` those checks cannot run.
"""

from __future__ import annotations

import json
import math
import stat
import zipfile
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import export

FORMAT = "pe-mjx-exported-policy"
VERSION = 1
PROGRAM = "policy.stablehlo"
META = "meta.json"


# What a file may declare (checked before anything is read or allocated from it).
MAX_META_BYTES = 1 << 20
MAX_PROGRAM_BYTES = 1 << 30
DEFLATE_MAX_RATIO = 1032  # deflate cannot expand a stream more than this
MAX_DIM = 1 << 16
MAX_INPUT_ELEMENTS = 1 << 26
DTYPES = ("float32", "bool", "int32")
TEAMS = ("pursuer", "evader")


def _read_member(archive: zipfile.ZipFile, name: str, file_size: int, limit: int) -> bytes:
    """One member's bytes, refused before reading when the sizes its headers declare are more
    than the file holds (compressed) or than `limit` (uncompressed)."""
    try:
        info = archive.getinfo(name)
    except KeyError:
        raise ValueError(f"it has no {name} member") from None
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise ValueError(f"its {name} uses compression method {info.compress_type}")
    ratio = 1 if info.compress_type == zipfile.ZIP_STORED else DEFLATE_MAX_RATIO
    if info.compress_size > file_size or info.file_size > ratio * info.compress_size + 64:
        raise ValueError(
            f"its {name} declares {info.file_size:,} bytes ({info.compress_size:,} compressed) in "
            f"a file of {file_size:,} bytes"
        )
    if info.file_size > limit:
        raise ValueError(f"its {name} declares {info.file_size:,} bytes, more than {limit:,}")
    with archive.open(info) as member:  # reads at most file_size bytes; checks the CRC-32
        data = member.read(info.file_size + 1)
    if len(data) != info.file_size:
        raise ValueError(f"its {name} holds {len(data):,} bytes, not {info.file_size:,}")
    return data


def _read_archive(path: Path) -> tuple[Any, bytes]:
    """(parsed meta.json, program bytes); `ValueError` for anything that is not a whole file."""
    try:
        status = path.stat()
        if not stat.S_ISREG(status.st_mode):  # /dev/zero was read until memory ran out
            what = "a directory" if stat.S_ISDIR(status.st_mode) else "a device or a pipe"
            raise OSError(f"it is {what}, not a policy file")
        size = status.st_size
        with zipfile.ZipFile(path) as archive:
            meta_bytes = _read_member(archive, META, size, MAX_META_BYTES)
            program = _read_member(archive, PROGRAM, size, MAX_PROGRAM_BYTES)
        meta = json.loads(meta_bytes.decode("utf-8"))
    except ValueError as err:
        raise ValueError(f"{path} is not a pe-mjx exported policy: {err}") from None
    except OSError as err:
        raise ValueError(f"{path}: cannot read it: {err.strerror or err}") from None
    except Exception as err:  # zipfile raises many types for a damaged archive
        raise ValueError(
            f"{path} is not a pe-mjx exported policy (damaged or truncated: "
            f"{type(err).__name__}: {err})"
        ) from None
    return meta, program


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _check_meta(meta: Any, path: Path) -> None:
    """The metadata's schema and bounds; `ValueError` naming the first bad field."""

    def bad(message: str) -> ValueError:
        return ValueError(f"{path} has invalid metadata: {message}")

    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"{path} is not a pe-mjx exported policy (format tag missing)")
    if meta.get("version") != VERSION or not _is_int(meta.get("version")):
        raise ValueError(
            f"{path} has exported-policy format version {meta.get('version')!r}; this loader "
            f"reads version {VERSION}"
        )
    if meta.get("team") not in TEAMS:
        raise bad(f"team must be one of {TEAMS}, got {meta.get('team')!r}")
    inputs = meta.get("inputs")
    if not isinstance(inputs, list) or not inputs:
        raise bad("inputs must be a non-empty list")
    names = set()
    for k, entry in enumerate(inputs):
        if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            raise bad(f"inputs[{k}] must be an object with a name")
        name, shape, dtype = entry["name"], entry.get("shape"), entry.get("dtype")
        if name in names:
            raise bad(f"input {name!r} is listed twice")
        names.add(name)
        if (
            not isinstance(shape, list)
            or not shape
            or not all(_is_int(d) and 0 <= d <= MAX_DIM for d in shape)
        ):
            raise bad(f"input {name!r} has shape {shape!r}; expected dims in [0, {MAX_DIM}]")
        if math.prod(shape) > MAX_INPUT_ELEMENTS:
            raise bad(f"input {name!r} has shape {shape}, more than {MAX_INPUT_ELEMENTS:,} entries")
        if dtype not in DTYPES:
            raise bad(f"input {name!r} has dtype {dtype!r}; expected one of {DTYPES}")
    rows = {entry["shape"][0] for entry in inputs}
    if len(rows) != 1 or 0 in rows:
        raise bad(f"the inputs disagree on the agent count (their first dims: {sorted(rows)})")
    table = meta.get("action_table")
    if not isinstance(table, dict):
        raise bad("action_table is missing")
    lengths = set()
    for key in ("v", "omega"):
        values = table.get(key)
        if (
            not isinstance(values, list)
            or not values
            or len(values) > MAX_DIM
            or not all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                for x in values
            )
        ):
            raise bad(f"action_table.{key} must be a non-empty list of finite numbers")
        lengths.add(len(values))
    if len(lengths) != 1:
        raise bad("action_table.v and action_table.omega differ in length")


def _check_program(exported: Any, meta: dict[str, Any], path: Path) -> None:
    """The program's calling convention against the metadata: the inputs' shapes and dtypes,
    and outputs (int32 [A], float32 [A, n_actions])."""
    want = [(tuple(i["shape"]), np.dtype(i["dtype"])) for i in meta["inputs"]]
    have = [(tuple(a.shape), np.dtype(a.dtype)) for a in exported.in_avals]
    if have != want:
        raise ValueError(
            f"{path}: its program takes {[f'{d}{list(s)}' for s, d in have]} but its metadata "
            f"declares {[f'{d}{list(s)}' for s, d in want]}"
        )
    rows, n_actions = want[0][0][0], len(meta["action_table"]["v"])
    outs = [(tuple(a.shape), np.dtype(a.dtype)) for a in exported.out_avals]
    expected = [((rows,), np.dtype("int32")), ((rows, n_actions), np.dtype("float32"))]
    if outs != expected:
        raise ValueError(
            f"{path}: its program returns {[f'{d}{list(s)}' for s, d in outs]}, not the actions "
            f"and logits of {rows} agents and {n_actions} actions"
        )


class ExportedPolicy:
    """A policy read from a `pe-mjx export` file.

    Attributes:
      team: "pursuer" or "evader".
      inputs: [(name, shape, dtype)] in call order, the shapes the file was exported for.
      speeds, turn_rates: float32 [n_actions], the (v, omega) of each action index.
      meta: everything in meta.json (game config, source run, ...).
    """

    def __init__(self, path: str | Path):
        path = Path(path)
        meta, program = _read_archive(path)
        _check_meta(meta, path)
        try:
            exported = export.deserialize(bytearray(program))
            _check_program(exported, meta, path)
        except ValueError as err:
            if str(err).startswith(str(path)):
                raise
            raise ValueError(f"{path}: its program cannot be read: {err}") from None
        except Exception as err:  # jax.export raises many types for a damaged program
            raise ValueError(
                f"{path}: its program cannot be read ({type(err).__name__}: {err})"
            ) from None
        self.meta = meta
        self.team = meta["team"]
        self.inputs = [(i["name"], tuple(i["shape"]), np.dtype(i["dtype"])) for i in meta["inputs"]]
        self.speeds = np.asarray(meta["action_table"]["v"], np.float32)
        self.turn_rates = np.asarray(meta["action_table"]["omega"], np.float32)
        self._exported = exported
        # One compile per input shape: padding, the program and the slicing fuse into one call.
        self._apply = jax.jit(self._unjitted_apply)

    @property
    def num_agents(self) -> int:
        return self.inputs[0][1][0]

    @property
    def num_actions(self) -> int:
        return len(self.speeds)

    def _check_shapes(self, obs: dict[str, Any]) -> int:
        """Every input present, within the exported shapes, with one agent count (returned)."""
        rows = None
        for name, shape, _ in self.inputs:
            if name not in obs:
                raise ValueError(f"observation has no {name!r} (expected {self.names})")
            have = tuple(np.shape(obs[name]))
            if len(have) != len(shape) or any(n > m for n, m in zip(have, shape, strict=True)):
                raise ValueError(
                    f"{name} has shape {have}; this file was exported for at most "
                    f"{shape} (re-export with a larger scene)"
                )
            rows = have[0] if rows is None else rows
            if have[0] != rows:
                raise ValueError(f"{name} has {have[0]} agents, {self.inputs[0][0]} has {rows}")
        assert rows is not None
        return rows

    def _padded(self, obs: dict[str, Any]) -> tuple[list[jax.Array], int]:
        rows = self._check_shapes(obs)
        args = []
        for name, shape, dtype in self.inputs:
            x = jnp.asarray(obs[name]).astype(dtype)
            args.append(jnp.pad(x, [(0, m - n) for n, m in zip(x.shape, shape, strict=True)]))
        return args, rows

    @property
    def names(self) -> list[str]:
        return [name for name, _, _ in self.inputs]

    def apply(self, obs: dict[str, Any]) -> tuple[jax.Array, jax.Array]:
        """(actions int32 [A], logits float32 [A, n_actions]) for one team's observation dict of
        one arena (SPEC 2.5 layout, `state.obs[team]`). Jittable."""
        names = set(self.names)
        obs = {k: v for k, v in obs.items() if k in names}
        self._check_shapes(obs)
        self._check_values(obs)
        return self._apply(obs)

    def _check_values(self, obs: dict[str, Any]) -> None:
        """Eagerly (not under `jit`): NaN or inf in an observation, or an agent whose action mask
        allows nothing, is a `ValueError`."""
        for name in self.names:
            x = obs.get(name)
            if x is None or isinstance(x, jax.core.Tracer):
                continue
            x = np.asarray(x)
            if np.issubdtype(x.dtype, np.inexact) and not np.all(np.isfinite(x)):
                bad = np.argwhere(~np.isfinite(x))[0].tolist()
                raise ValueError(
                    f"observation {name} holds {x[tuple(bad)]} at {bad}: observations must be "
                    f"finite"
                )
            if name == "action_mask" and x.ndim >= 1 and x.size:
                none = ~np.any(x.astype(bool), axis=-1)
                if np.any(none):
                    agents = (
                        np.flatnonzero(none).tolist()
                        if none.ndim == 1
                        else np.argwhere(none).tolist()
                    )
                    raise ValueError(
                        f"action_mask allows no action for agent(s) {agents}: every agent needs "
                        f"at least one valid action (the env always leaves a stop action)"
                    )

    def _unjitted_apply(self, obs: dict[str, Any]) -> tuple[jax.Array, jax.Array]:
        args, rows = self._padded(obs)
        actions, logits = self._exported.call(*args)
        return actions[:rows], logits[:rows]

    def __call__(self, obs: dict[str, Any], rng: Any = None) -> jax.Array:
        """Greedy actions int32 [A]; the signature of pe-mjx policies, `rng` is unused."""
        return self.apply(obs)[0]

    def commands(self, obs: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """(v [A] in m/s, omega [A] in rad/s) of the greedy actions."""
        actions = np.asarray(self(obs))
        return self.speeds[actions], self.turn_rates[actions]


def load(path: str | Path) -> ExportedPolicy:
    """Reads a `pe-mjx export` file; ValueError if it is not one."""
    return ExportedPolicy(path)
