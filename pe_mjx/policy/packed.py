"""Packed policies: a trained run's policies and metadata in one file, for shipping and keeping.

A run of `pe-mjx train` keeps orbax checkpoints (`checkpoints/<step>/`, about 32 files a step),
which can be resumed. What only needs to *play* (the shipped policies, the policies that a
committed evaluation plays) is packed instead by `pe-mjx ship`: a directory with the run's
`config.json` and one `policy.msgpack` holding

    {"format": "pe-mjx-policy", "version": 1,
     "meta": "<the checkpoint's metadata as JSON, its step included>",
     "policies": {team: {"params": ..., "normalizer": ...}}}

serialised by flax (`flax.serialization`, MessagePack: plain arrays and strings, no pickle). The
policy store (`pe_mjx.policy.store`) reads a packed directory wherever it reads a run; the arrays
are checked against the shapes their network config implies before they are used. One file of a
few hundred kB instead of a tree of files keeps a clone small.

A copy that only *reads* differently from a packed policy beside it (`pe-mjx ship --nearest-k`,
`--length-unit`: the same parameters, another network config) shares that policy's parameters
instead of holding them again (version 2, a few kB):

    {"format": "pe-mjx-policy", "version": 2, "meta": "<its own metadata>",
     "parameters_of": {"policy": "<the sibling directory's name>", "sha256": "<of its file>"}}

The owner must sit in the same directory and hold its own parameters (one level, no chains); its
file is read with the same cap and must still hash to the recorded digest, so an owner that was
replaced or damaged is one error naming both rather than another policy played silently.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

from pe_mjx import outputs
from pe_mjx.names import POLICY_NAME

PACKED_FILE = "policy.msgpack"
FORMAT = "pe-mjx-policy"
VERSION = 1
SHARED_VERSION = 2
"""The version of a file that shares a sibling's parameters (`parameters_of`)."""
MAX_BYTES = 64 << 20
"""Largest packed file read (a 20-5-8 policy pair is about 0.2 MB)."""


class PackedPolicyError(ValueError):
    """A packed policy file that cannot be read (damaged, too large, or of another format)."""


def is_packed(run_dir: str | Path) -> bool:
    """Whether `run_dir` is a packed policy directory."""
    return (Path(run_dir) / PACKED_FILE).is_file()


def write(
    dest: str | Path,
    meta: dict[str, Any],
    policies: dict[str, Any] | None = None,
    parameters_of: str | Path | None = None,
) -> Path:
    """Writes `dest/policy.msgpack` (a temporary beside it, then one rename).

    Args:
      dest: the packed policy's directory (created).
      meta: the checkpoint's metadata (JSON-serialisable, with its `step`).
      policies: team -> {"params", "normalizer"} as restored (any arrays); or
      parameters_of: instead of `policies`, a packed policy in the same directory as `dest`
        whose parameters this one shares (it must hold them itself; its digest is recorded).
    """
    dest = Path(dest)
    if (policies is None) == (parameters_of is None):
        raise ValueError("give the policies or the packed policy whose parameters are shared")
    state: dict[str, Any] = {"format": FORMAT, "meta": json.dumps(meta, sort_keys=True)}
    if parameters_of is None:
        state["version"] = VERSION
        state["policies"] = {
            team: serialization.to_state_dict(jax.tree.map(np.asarray, tree))
            for team, tree in policies.items()
        }
    else:
        owner = Path(parameters_of)
        beside = owner.resolve().parent == dest.resolve().parent and owner.name != dest.name
        if not (beside and re.fullmatch(POLICY_NAME, owner.name)):
            raise ValueError(f"{owner} is not a packed policy beside {dest}")
        data = _read_capped(owner / PACKED_FILE)
        _parse(data, owner / PACKED_FILE, versions=(VERSION,))  # holds its own parameters
        state["version"] = SHARED_VERSION
        state["parameters_of"] = {"policy": owner.name, "sha256": _digest(data)}
    dest.mkdir(parents=True, exist_ok=True)
    path = dest / PACKED_FILE
    tmp = dest / f".{PACKED_FILE}.tmp-{os.getpid()}"
    try:
        tmp.write_bytes(serialization.msgpack_serialize(state))
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return path


def owner(run_dir: str | Path) -> Path:
    """The packed directory that holds `run_dir`'s parameters: itself, or the sibling whose
    parameters it shares."""
    path = Path(run_dir) / PACKED_FILE
    state = _parse(_read_capped(path), path, versions=(VERSION, SHARED_VERSION))
    if state["version"] == VERSION:
        return Path(run_dir)
    return _shared(state, path)[0].parent


def read(run_dir: str | Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(metadata, team -> state dict of its policy) of a packed directory (the shared owner's
    policies for a version 2 file); the metadata is not yet validated (the store checks it) and
    the arrays not yet checked against any shape.

    Raises:
      PackedPolicyError: the file (or its owner's) is over `MAX_BYTES`, not MessagePack, not
        this format, or an owner that is missing or no longer the one it shared.
    """
    path = Path(run_dir) / PACKED_FILE
    state = _parse(_read_capped(path), path, versions=(VERSION, SHARED_VERSION))
    meta = state["meta"]
    if state["version"] == VERSION:
        return meta, state["policies"]
    owner_file, digest = _shared(state, path)
    try:
        data = _read_capped(owner_file)
    except PackedPolicyError:
        raise PackedPolicyError(
            f"{path} shares the parameters of {owner_file.parent}, which cannot be read"
        ) from None
    if _digest(data) != digest:
        raise PackedPolicyError(
            f"{path} shares the parameters of {owner_file.parent}, which changed since it was "
            "written (its sha256 differs): ship it again from its source"
        )
    return meta, _parse(data, owner_file, versions=(VERSION,))["policies"]


def _shared(state: dict[str, Any], path: Path) -> tuple[Path, str]:
    """(the owner's file, its recorded digest) of a version 2 file at `path`."""
    shared = state.get("parameters_of")
    name = shared.get("policy") if isinstance(shared, dict) else None
    digest = shared.get("sha256") if isinstance(shared, dict) else None
    if not (isinstance(name, str) and re.fullmatch(POLICY_NAME, name) and isinstance(digest, str)):
        raise PackedPolicyError(f"{path} shares parameters but does not say whose")
    return path.parent.parent / name / PACKED_FILE, digest


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _read_capped(path: Path) -> bytes:
    """The file's bytes, at most `MAX_BYTES` (a FIFO or a device is refused, not waited on)."""
    try:
        return outputs.read_bytes(path, MAX_BYTES)
    except outputs.OutputError as err:
        raise PackedPolicyError(str(err)) from None


def _parse(data: bytes, path: Path, versions: tuple[int, ...]) -> dict[str, Any]:
    """The file's state with its metadata parsed; checks the header and the version's fields."""
    try:
        state = serialization.msgpack_restore(data)
    except Exception as err:  # msgpack raises many types for damaged data
        raise PackedPolicyError(f"{path} is not a packed policy ({type(err).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise PackedPolicyError(f"{path} is not a packed policy (no {FORMAT!r} header)")
    version = state.get("version")
    if version not in (VERSION, SHARED_VERSION):
        raise PackedPolicyError(
            f"{path} is packed policy version {version!r}; this pe-mjx reads versions "
            f"{VERSION} and {SHARED_VERSION}"
        )
    if version not in versions:  # an owner that itself shares: no chains
        raise PackedPolicyError(f"{path} does not hold its own parameters")
    meta, policies = state.get("meta"), state.get("policies")
    if not isinstance(meta, str) or (version == VERSION and not isinstance(policies, dict)):
        raise PackedPolicyError(f"{path} lacks its metadata or its policies")
    try:
        state["meta"] = json.loads(meta)
    except ValueError:
        raise PackedPolicyError(f"{path} holds metadata that is not JSON") from None
    return state


def restore(state: Any, abstract: Any) -> Any:
    """`abstract` (a tree of shape structs) filled with the arrays of `state` (one team's state
    dict from `read`). Raises PackedPolicyError if the tree's structure differs; the caller
    checks shapes and dtypes (`pe_mjx.policy.store.shape_mismatch`)."""
    try:
        tree = serialization.from_state_dict(abstract, state)
    except Exception as err:  # flax raises several types for a state of another shape
        raise PackedPolicyError(f"its arrays do not fit the network: {err}") from None
    leaves = jax.tree.leaves(tree)
    if not all(isinstance(x, np.ndarray | np.generic | jax.Array) for x in leaves):
        raise PackedPolicyError("it lacks some of the network's arrays")
    # MessagePack gives 0-d arrays back as scalars; Brax's counters rebuild as jax arrays.
    return jax.tree.map(np.asarray, tree)


__all__ = ["PACKED_FILE", "PackedPolicyError", "is_packed", "owner", "read", "restore", "write"]
