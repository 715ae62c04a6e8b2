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
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

PACKED_FILE = "policy.msgpack"
FORMAT = "pe-mjx-policy"
VERSION = 1
MAX_BYTES = 64 << 20
"""Largest packed file read (a 20-5-8 policy pair is about 0.2 MB)."""


class PackedPolicyError(ValueError):
    """A packed policy file that cannot be read (damaged, too large, or of another format)."""


def is_packed(run_dir: str | Path) -> bool:
    """Whether `run_dir` is a packed policy directory."""
    return (Path(run_dir) / PACKED_FILE).is_file()


def write(dest: str | Path, meta: dict[str, Any], policies: dict[str, Any]) -> Path:
    """Writes `dest/policy.msgpack` (a temporary beside it, then one rename).

    Args:
      dest: the packed policy's directory (created).
      meta: the checkpoint's metadata (JSON-serialisable, with its `step`).
      policies: team -> {"params", "normalizer"} as restored (any arrays).
    """
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    state = {
        "format": FORMAT,
        "version": VERSION,
        "meta": json.dumps(meta, sort_keys=True),
        "policies": {
            team: serialization.to_state_dict(jax.tree.map(np.asarray, tree))
            for team, tree in policies.items()
        },
    }
    path = dest / PACKED_FILE
    tmp = dest / f".{PACKED_FILE}.tmp-{os.getpid()}"
    try:
        tmp.write_bytes(serialization.msgpack_serialize(state))
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    return path


def read(run_dir: str | Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """(metadata, team -> state dict of its policy) of a packed directory; the metadata is not
    yet validated (the store checks it) and the arrays not yet checked against any shape.

    Raises:
      PackedPolicyError: the file is over `MAX_BYTES`, not MessagePack, or not this format.
    """
    path = Path(run_dir) / PACKED_FILE
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as err:
        raise PackedPolicyError(f"{path} cannot be read: {err.strerror or err}") from None
    if len(data) > MAX_BYTES:
        raise PackedPolicyError(f"{path} is larger than {MAX_BYTES >> 20} MB")
    try:
        state = serialization.msgpack_restore(data)
    except Exception as err:  # msgpack raises many types for damaged data
        raise PackedPolicyError(f"{path} is not a packed policy ({type(err).__name__})") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise PackedPolicyError(f"{path} is not a packed policy (no {FORMAT!r} header)")
    if state.get("version") != VERSION:
        raise PackedPolicyError(
            f"{path} is packed policy version {state.get('version')!r}; this pe-mjx reads "
            f"version {VERSION}"
        )
    meta, policies = state.get("meta"), state.get("policies")
    if not isinstance(meta, str) or not isinstance(policies, dict):
        raise PackedPolicyError(f"{path} lacks its metadata or its policies")
    try:
        meta = json.loads(meta)
    except ValueError:
        raise PackedPolicyError(f"{path} holds metadata that is not JSON") from None
    return meta, policies


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


__all__ = ["PACKED_FILE", "PackedPolicyError", "is_packed", "read", "restore", "write"]
