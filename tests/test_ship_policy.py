"""tools/ship_policy.py --nearest-k: local attention over a run's parameters, and the shipped
`mix-20-5-8-3m-k4` made that way."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import pytest

import pe_mjx
from pe_mjx.policy.inference import normalize_obs
from pe_mjx.policy.resolve import resolve_policy
from pe_mjx.policy.store import read_meta
from tests.tool_modules import load_tool

ROOT = Path(__file__).resolve().parent.parent
FULL = ROOT / "assets" / "policies" / "mix-20-5-8-3m"
LOCAL = "mix-20-5-8-3m-k4"


def _tool():
    return load_tool("ship_policy")


@pytest.fixture(scope="module")
def derived(tmp_path_factory):
    tool = _tool()
    dest = tmp_path_factory.mktemp("ship")
    return tool.ship(tool.Args(FULL, "k3", dest=dest, nearest_k=3))


def test_nearest_k_is_written_everywhere_and_the_source_recorded(derived):
    meta = read_meta(derived)
    assert {t: c["nearest_k"] for t, c in meta["network_configs"].items()} == {
        "pursuer": 3,
        "evader": 3,
    }
    assert meta["experiment"]["pursuer"]["network"]["nearest_k"] == 3
    config = json.loads((derived / "config.json").read_text())
    assert config["experiment"]["evader"]["network"]["nearest_k"] == 3
    assert config["derived_from"]["network_configs"]["pursuer"]["nearest_k"] is None
    assert str(FULL) in config["derived_from"]["run"]


def test_a_bad_k_is_one_clear_error(tmp_path):
    tool = _tool()
    with pytest.raises(SystemExit, match="--nearest-k must be >= 1"):
        tool.ship(tool.Args(FULL, "k0", dest=tmp_path, nearest_k=0))


@pytest.mark.parametrize("team", ["pursuer", "evader"])
def test_local_attention_changes_what_is_read_not_the_parameters(derived, team):
    """Same parameters; where no type has more than k entities the logits are identical
    (nothing is dropped), and in a crowd they differ (the far entities are)."""
    full = resolve_policy(FULL, team)
    local = resolve_policy(derived, team)
    assert local.label.startswith(f"{team[0].upper()}_MIX-k3(")
    for a, b in zip(jax.tree.leaves(full.variables), jax.tree.leaves(local.variables), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    for preset, same in (("2-1-1", True), ("20-5-8", False)):
        env = pe_mjx.make(preset, backend="kinematic")
        obs = jax.jit(env.reset)(jax.random.key(0)).obs[team]
        logits = [
            p.network.apply(p.variables["params"], normalize_obs(obs, p.variables["normalizer"]))[0]
            for p in (full, local)
        ]
        assert bool(np.allclose(logits[0], logits[1], atol=1e-5)) == same, preset


def test_the_shipped_local_policy_is_the_3m_mix_with_k4():
    meta, source = read_meta(LOCAL), read_meta(FULL)
    assert {c["nearest_k"] for c in meta["network_configs"].values()} == {4}
    assert meta["env_steps"] == source["env_steps"] == 3_000_320
    for team in ("pursuer", "evader"):
        a, b = resolve_policy(LOCAL, team), resolve_policy(FULL, team)
        for x, y in zip(jax.tree.leaves(a.variables), jax.tree.leaves(b.variables), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
