"""pe_mjx.policy.resolve: one resolver for builtin names, run directories and shipped policies."""

from __future__ import annotations

import dataclasses
import re

import jax
import numpy as np
import pytest

from pe_mjx import get_preset
from pe_mjx.policy.inference import dummy_obs
from pe_mjx.policy.resolve import load_policy, resolve_policy
from pe_mjx.policy.store import CheckpointError

SHIPPED = "mix-20-5-8"


def test_builtin_policies_resolve_without_a_checkpoint():
    config = get_preset("4-1-2")
    p = resolve_policy("scripted", "pursuer", config)
    assert (p.label, p.method, p.shape_key, p.learned) == (
        "P_scripted",
        "scripted",
        "builtin:scripted",
        False,
    )
    actions = p.apply(None, dummy_obs(config, "pursuer"), jax.random.key(0))
    assert actions.shape == (4,)
    with pytest.raises(ValueError, match="env config"):
        resolve_policy("random", "evader", None)


def test_shipped_policy_resolves_once_with_both_forms():
    config = get_preset("4-1-2")
    p = resolve_policy(SHIPPED, "evader", config, deterministic=True)
    assert p.learned and p.method == "mix" and p.label == "E_MIX(20,5,8)"
    assert p.network is not None and p.network_config.encoder == "mix"
    obs, key = dummy_obs(config, "evader"), jax.random.key(1)
    # The closed-over and the argument forms are the same policy.
    np.testing.assert_array_equal(p(obs, key), p.apply(p.variables, obs, key))
    np.testing.assert_array_equal(p(obs, key), load_policy(SHIPPED, "evader", True)(obs, key))


def test_errors_name_the_problem(tmp_path):
    config = get_preset("4-1-2")
    with pytest.raises(CheckpointError, match="unknown team"):
        resolve_policy(SHIPPED, "referee", config)
    with pytest.raises(CheckpointError):
        resolve_policy(tmp_path / "nowhere", "pursuer", config)
    other = config.replace(
        pursuer=dataclasses.replace(config.pursuer, num_speeds=config.pursuer.num_speeds + 1)
    )
    with pytest.raises(CheckpointError, match="actions"):
        resolve_policy(SHIPPED, "pursuer", other)
    # Wrong types: errors naming the argument (a preset's name failed inside the scripted
    # policy with "'str' object has no attribute 'team'"; "" read the working directory).
    with pytest.raises(TypeError, match="env_config must be an EnvConfig"):
        resolve_policy("scripted", "pursuer", "4-1-2")
    with pytest.raises(TypeError, match="spec must be a str or a Path, got NoneType"):
        load_policy(None, "pursuer")
    with pytest.raises(CheckpointError, match="empty policy spec"):
        load_policy("", "pursuer")
    # A flag given as a string ("no" is truthy) is refused rather than read as greedy.
    with pytest.raises(TypeError, match="deterministic must be True or False, got 'no'"):
        load_policy(SHIPPED, "pursuer", deterministic="no")
    with pytest.raises(TypeError, match="fallback must be True or False, got 1"):
        resolve_policy(SHIPPED, "pursuer", config, fallback=1)


@pytest.mark.parametrize("layout", ["packed", "orbax"])
def test_a_config_that_disagrees_with_the_arrays_is_refused_before_they_are_read(tmp_path, layout):
    """A policy whose network config says twice the width its arrays have is one clear error that
    names the array and both shapes, found before any array is read (orbax: from its metadata;
    orbax read the arrays and failed half-way, leaving coroutines unawaited)."""
    import json
    import shutil
    import warnings

    from pe_mjx.policy import packed
    from pe_mjx.policy.shipped import policies_dir
    from tests.policy_copies import orbax_copy

    def wider(meta: dict) -> int:
        width = meta["network_configs"]["pursuer"]["width"]
        meta["network_configs"]["pursuer"]["width"] = 2 * width
        meta["experiment"]["pursuer"]["network"]["width"] = 2 * width
        return width

    run = tmp_path / "run"
    if layout == "packed":
        shutil.copytree(policies_dir() / SHIPPED, run)
        meta, policies = packed.read(run)
        width = wider(meta)
        packed.write(run, meta, policies)
    else:
        orbax_copy(SHIPPED, run)
        path = next((run / "checkpoints").iterdir()) / "meta" / "metadata"
        meta = json.loads(path.read_text())
        width = wider(meta)
        path.write_text(json.dumps(meta))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an unawaited read would warn
        with pytest.raises(CheckpointError) as err:
            resolve_policy(str(run), "pursuer", get_preset("20-5-8"))
    message = str(err.value)
    assert "does not match its network config" in message, message
    shapes = rf"is float32\[{width}\b.*where float32\[{2 * width}\b.* is needed"
    assert re.search(shapes, message), message
    # The other team's arrays still fit its own config.
    assert resolve_policy(str(run), "evader", get_preset("20-5-8")).team == "evader"


def test_fingerprint_is_what_decides_play_not_where_it_came_from(tmp_path):
    import shutil

    from pe_mjx.policy.shipped import policies_dir

    config = get_preset("20-5-8")
    base = resolve_policy("mix-20-5-8-3m", "pursuer", config)
    # The same checkpoint under another path: same fingerprint (the source does not enter it).
    shutil.copytree(policies_dir() / "mix-20-5-8-3m", tmp_path / "copy")
    copy = resolve_policy(str(tmp_path / "copy"), "pursuer", config)
    assert copy.source != base.source and copy.fingerprint == base.fingerprint
    assert len(base.fingerprint) == 32
    # Same parameters, another way of reading them (4 nearest per type): another policy.
    local = resolve_policy("mix-20-5-8-3m-k4", "pursuer", config)
    np.testing.assert_array_equal(
        jax.tree.leaves(local.variables)[0], jax.tree.leaves(base.variables)[0]
    )
    assert local.fingerprint != base.fingerprint
    # Another checkpoint, the other team, greedy actions, builtin policies: all differ.
    others = [
        resolve_policy("mix-20-5-8", "pursuer", config),
        resolve_policy("mix-20-5-8-3m", "evader", config),
        resolve_policy("mix-20-5-8-3m", "pursuer", config, deterministic=True),
        resolve_policy("scripted", "pursuer", config),
        resolve_policy("random", "pursuer", config),
    ]
    prints = {p.fingerprint for p in [base, local, *others]}
    assert len(prints) == 7
    assert resolve_policy("scripted", "pursuer", config).fingerprint == others[3].fingerprint
