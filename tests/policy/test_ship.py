"""pe_mjx/policy/ship.py (`pe-mjx ship`): policy-only copies of a run; --nearest-k and
--length-unit: local attention and neighbour lengths in metres over a run's parameters, and the
shipped policies made that way."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest

import pe_mjx
from pe_mjx.policy.inference import in_length_unit, normalize_obs
from pe_mjx.policy.resolve import resolve_policy
from pe_mjx.policy.ship import derived_source, ship_policy
from pe_mjx.policy.store import read_meta

ROOT = Path(__file__).resolve().parents[2]
FULL = ROOT / "assets" / "policies" / "mix-20-5-8-3m"
LOCAL = "mix-20-5-8-3m-k4"
PACKED = "policy.msgpack"


@pytest.fixture(scope="module")
def derived(tmp_path_factory):
    dest = tmp_path_factory.mktemp("ship")
    return ship_policy(FULL, "k3", dest=dest, nearest_k=3)[0]


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
    assert derived_source(config) == str(FULL) and derived_source({"seed": 0}) is None


def test_a_bad_k_is_one_clear_error(tmp_path):
    with pytest.raises(ValueError, match="--nearest-k must be None or >= 1, got 0"):
        ship_policy(FULL, "k0", dest=tmp_path, nearest_k=0)


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


def test_a_bad_length_unit_is_one_clear_error(tmp_path):
    message = "--length-unit must be None or a positive number of metres"
    with pytest.raises(ValueError, match=message):
        ship_policy(FULL, "m0", dest=tmp_path, length_unit=-5.0)
    assert not (tmp_path / "m0").exists()


def test_a_length_unit_of_the_training_radius_plays_as_before_there_and_in_metres_elsewhere(
    tmp_path,
):
    """mix-20-5-8-3m (trained in a 5 m arena) shipped with neighbour lengths in units of 5 m:
    the same logits at 20-5-8; at 8-2-4 (3.5 m) the original network's logits on observations
    whose neighbour lengths are multiplied by 3.5 / 5, which differ from the original's."""
    metric = ship_policy(FULL, "m5", dest=tmp_path, length_unit=5.0)[0]
    config = json.loads((metric / "config.json").read_text())
    assert config["experiment"]["pursuer"]["network"]["length_unit"] == 5.0
    assert config["derived_from"]["length_unit"] == 5.0
    for preset, scale in (("20-5-8", 1.0), ("8-2-4", 0.7)):
        env = pe_mjx.make(preset, backend="kinematic")
        full = resolve_policy(FULL, "pursuer", env.config)
        in_metres = resolve_policy(metric, "pursuer", env.config)
        assert in_metres.label.startswith("P_MIX-5m(20,5,8)")
        obs = jax.jit(env.reset)(jax.random.key(0)).obs["pursuer"]
        scaled = in_length_unit(obs, scale)
        key = jax.random.key(3)
        np.testing.assert_array_equal(in_metres(obs, key), full(scaled, key))
        logits = [
            full.network.apply(
                full.variables["params"], normalize_obs(o, full.variables["normalizer"])
            )[0]
            for o in (obs, scaled)
        ]
        assert bool(np.allclose(logits[0], logits[1], atol=1e-5)) == (scale == 1.0), preset


def test_the_shipped_local_policy_is_the_3m_mix_with_k4():
    """It shares the 3M MIX's parameters file (a few kB in the package, not a second copy)."""
    from pe_mjx.policy import packed

    assert packed.owner(FULL.parent / LOCAL).resolve() == FULL.resolve()
    meta, source = read_meta(LOCAL), read_meta(FULL)
    assert {c["nearest_k"] for c in meta["network_configs"].values()} == {4}
    assert meta["env_steps"] == source["env_steps"] == 3_000_320
    for team in ("pursuer", "evader"):
        a, b = resolve_policy(LOCAL, team), resolve_policy(FULL, team)
        for x, y in zip(jax.tree.leaves(a.variables), jax.tree.leaves(b.variables), strict=True):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_a_copy_shipped_beside_its_packed_source_shares_its_parameters(tmp_path):
    """--nearest-k into the source's own directory writes a few kB that point at the source's
    file: the same arrays and fingerprint as a whole copy elsewhere; shipped again from that
    copy it points at the owner (no chains); once the owner changes it is one clear error."""
    from pe_mjx.policy import packed
    from pe_mjx.policy.store import CheckpointError

    home = tmp_path / "runs"
    home.mkdir()
    source = home / "mix"
    shutil.copytree(FULL, source)
    near, _ = ship_policy(source, "mix-k4", dest=home, nearest_k=4)
    whole, _ = ship_policy(source, "mix-k4", dest=tmp_path / "elsewhere", nearest_k=4)
    assert (near / PACKED).stat().st_size < 10_000 < (whole / PACKED).stat().st_size
    assert packed.owner(near) == source and packed.owner(whole) == whole
    assert read_meta(near) == read_meta(whole)
    for team in ("pursuer", "evader"):
        a, b = resolve_policy(near, team), resolve_policy(whole, team)
        assert a.network_config.nearest_k == 4 and a.fingerprint == b.fingerprint
    again, _ = ship_policy(near, "mix-m", dest=home, length_unit=5.0)
    assert packed.owner(again) == source
    assert resolve_policy(again, "evader").network_config.length_unit == 5.0
    itself, _ = ship_policy(source, "mix", dest=home, nearest_k=2, replace=True)
    assert packed.owner(itself) == source  # replacing its own source: a whole copy
    with pytest.raises(CheckpointError, match="changed since it was written") as err:
        read_meta(near)
    assert "\n" not in str(err.value) and str(source) in str(err.value)
    shutil.rmtree(source)
    with pytest.raises(CheckpointError, match=f"shares the parameters of {source}, which cannot"):
        resolve_policy(again, "pursuer")


def test_pe_mjx_ship_copies_the_policies_only_and_refuses_to_replace(tmp_path, capsys):
    """The subcommand that replaced tools/ship_policy.py: same arguments, one error line. From a
    run's orbax checkpoint it writes a packed policy (config.json and policy.msgpack) that plays
    the same arrays."""
    from pe_mjx.cli import main
    from tests.policy_copies import orbax_copy

    run = orbax_copy("mix-20-5-8-3m", tmp_path / "run")
    out = tmp_path / "out"
    main(["ship", str(run), "copy", "--dest", str(out)])
    assert f"as {out / 'copy'}" in capsys.readouterr().out
    assert sorted(p.name for p in (out / "copy").iterdir()) == ["config.json", "policy.msgpack"]
    assert read_meta(out / "copy")["step"] == read_meta(run)["step"]
    for team in ("pursuer", "evader"):
        a = resolve_policy(out / "copy", team).variables
        b = resolve_policy("mix-20-5-8-3m", team).variables
        pairs = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
        assert all(np.array_equal(x, y) for x, y in pairs)
    for argv in (
        ["ship", str(run), "copy", "--dest", str(out)],  # exists, no --replace
        ["ship", str(FULL), "k0", "--dest", str(out), "--nearest-k", "0"],
        ["ship", str(tmp_path / "missing"), "x", "--dest", str(out)],
        ["ship", str(FULL), "../x", "--dest", str(out)],
    ):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and err.startswith("pe-mjx: error:"), err
    assert sorted(p.name for p in out.iterdir()) == ["copy"]
