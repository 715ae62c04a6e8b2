"""Packed policies: one file per policy copy, read back bit for bit, refused whole when damaged."""

from __future__ import annotations

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
