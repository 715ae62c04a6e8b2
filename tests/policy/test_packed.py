"""Packed policies: one file per policy copy, read back bit for bit, refused whole when damaged."""

from __future__ import annotations

import json
import os

import jax
import numpy as np
import pytest

from pe_mjx.policy import packed
from pe_mjx.policy.packed import PACKED_FILE, PackedPolicyError
from pe_mjx.policy.store import CheckpointError, read_meta, restore_policy_params


@pytest.fixture(scope="module")
def packed_copy(tmp_path_factory):
    """The shipped `mix-20-5-8` packed afresh from its own restored arrays."""
    dest = tmp_path_factory.mktemp("packed") / "copy"
    meta = read_meta("mix-20-5-8")
    policies = {t: restore_policy_params("mix-20-5-8", t).variables for t in ("pursuer", "evader")}
    packed.write(dest, meta, policies)
    (dest / "config.json").write_text("{}")
    return dest


def test_a_packed_copy_restores_the_same_arrays(packed_copy):
    assert packed.is_packed(packed_copy)
    for team in ("pursuer", "evader"):
        here = restore_policy_params(packed_copy, team)
        there = restore_policy_params("mix-20-5-8", team)
        assert here.net_config == there.net_config and here.env_config == there.env_config
        pairs = zip(jax.tree.leaves(here.variables), jax.tree.leaves(there.variables), strict=True)
        assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in pairs)
    assert read_meta(packed_copy)["step"] == read_meta("mix-20-5-8")["step"]


def _damaged(src, tmp_path, data: bytes):
    dest = tmp_path / "damaged"
    dest.mkdir()
    (dest / "config.json").write_bytes((src / "config.json").read_bytes())
    (dest / PACKED_FILE).write_bytes(data)
    return dest


@pytest.mark.parametrize("cut", [0, 1, 17, 1000, -1000, -1])
def test_a_truncated_file_is_one_clear_error(packed_copy, tmp_path, cut):
    data = (packed_copy / PACKED_FILE).read_bytes()
    damaged = _damaged(packed_copy, tmp_path, data[:cut])
    with pytest.raises(CheckpointError, match=PACKED_FILE) as err:
        restore_policy_params(damaged, "pursuer")
    assert "\n" not in str(err.value)


def test_arrays_of_another_shape_or_format_are_refused(packed_copy, tmp_path):
    meta, policies = packed.read(packed_copy)
    policies["pursuer"]["params"] = jax.tree.map(
        lambda x: x[..., :1], policies["pursuer"]["params"]
    )
    dest = tmp_path / "reshaped"
    packed.write(dest, meta, policies)
    with pytest.raises(CheckpointError, match="does not match its network config"):
        restore_policy_params(dest, "pursuer")
    other = _damaged(packed_copy, tmp_path, b"\x81\xa6format\xa5other")
    with pytest.raises(CheckpointError, match="not a packed policy"):
        read_meta(other)


def test_a_file_over_the_cap_is_refused_before_it_is_read(packed_copy, tmp_path, monkeypatch):
    monkeypatch.setattr(packed, "MAX_BYTES", 1000)
    with pytest.raises(PackedPolicyError, match="larger than"):
        packed.read(packed_copy)


def _shared_file(tmp_path, packed_copy, parameters_of):
    """A version 2 file beside a copy of `packed_copy`, naming `parameters_of` as its owner."""
    from flax import serialization

    owner = tmp_path / "owner"
    owner.mkdir()
    (owner / PACKED_FILE).write_bytes((packed_copy / PACKED_FILE).read_bytes())
    dest = tmp_path / "shared"
    dest.mkdir()
    meta = json.dumps(packed.read(packed_copy)[0])
    state = {"format": "pe-mjx-policy", "version": 2, "meta": meta, "parameters_of": parameters_of}
    (dest / PACKED_FILE).write_bytes(serialization.msgpack_serialize(state))
    return owner, dest


@pytest.mark.parametrize(
    "parameters_of",
    [None, "owner", {"policy": "../owner", "sha256": "0"}, {"policy": "/etc", "sha256": "0"}],
)
def test_a_shared_file_names_a_sibling_or_is_refused(packed_copy, tmp_path, parameters_of):
    """It can only name a neighbour (no separators, no `..`), with a digest."""
    _, dest = _shared_file(tmp_path, packed_copy, parameters_of)
    with pytest.raises(CheckpointError, match="shares parameters but does not say whose"):
        read_meta(dest)


def test_a_shared_file_reads_its_owners_arrays_only_while_they_hash_the_same(packed_copy, tmp_path):
    owner, dest = _shared_file(tmp_path, packed_copy, None)
    packed.write(dest, packed.read(packed_copy)[0], parameters_of=owner)
    here, there = restore_policy_params(dest, "evader"), restore_policy_params(owner, "evader")
    pairs = zip(jax.tree.leaves(here.variables), jax.tree.leaves(there.variables), strict=True)
    assert all(np.array_equal(a, b) for a, b in pairs)
    with pytest.raises(PackedPolicyError, match="does not hold its own parameters"):
        packed.write(tmp_path / "third", {"step": 0}, parameters_of=dest)  # no chains
    with pytest.raises(ValueError, match="is not a packed policy beside"):
        packed.write(tmp_path / "x" / "far", {"step": 0}, parameters_of=owner)
    data = bytearray((owner / PACKED_FILE).read_bytes())
    data[-1] ^= 1  # one bit of one parameter
    (owner / PACKED_FILE).write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match="changed since it was written"):
        restore_policy_params(dest, "evader")


def test_a_newer_format_version_names_the_versions_read(packed_copy, tmp_path):
    from flax import serialization

    other = _damaged(
        packed_copy,
        tmp_path,
        serialization.msgpack_serialize({"format": "pe-mjx-policy", "version": 3, "meta": "{}"}),
    )
    with pytest.raises(CheckpointError, match="version 3; this pe-mjx reads versions 1 and 2"):
        read_meta(other)


@pytest.mark.timeout(60)  # before the capped reader, open() waited for a writer
def test_an_owner_that_is_a_fifo_is_refused_at_once(packed_copy, tmp_path):
    """A shared file names its owner by a name only; what sits there is read with the capped
    reader, so a FIFO with no writer reads empty (its bytes are not the recorded ones): one
    error, not a wait."""
    owner, dest = _shared_file(tmp_path, packed_copy, None)
    packed.write(dest, packed.read(packed_copy)[0], parameters_of=owner)
    (owner / PACKED_FILE).unlink()
    os.mkfifo(owner / PACKED_FILE)
    with pytest.raises(CheckpointError, match="changed since it was written"):
        read_meta(dest)
    fifo = tmp_path / "fifo"
    fifo.mkdir()
    os.mkfifo(fifo / PACKED_FILE)
    with pytest.raises(PackedPolicyError, match="is not a packed policy"):
        packed.read(fifo)
