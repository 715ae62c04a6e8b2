"""The policies shipped under assets/ load from their path alone and play valid actions."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

import pe_mjx
from pe_mjx.names import TEAMS
from pe_mjx.policy.shipped import shipped_names
from pe_mjx.policy.store import CheckpointError, read_meta

SHIPPED = Path(__file__).resolve().parents[2] / "assets" / "policies" / "mix-20-5-8"


def test_shipped_policy_metadata():
    meta = read_meta(SHIPPED)
    assert meta["env_config"]["name"] == "20-5-8"
    assert {t: c["encoder"] for t, c in meta["network_configs"].items()} == {
        "pursuer": "mix",
        "evader": "mix",
    }


@pytest.mark.parametrize("preset", ["20-5-8", "24-6-12"])
def test_shipped_policies_play_valid_actions(preset):
    """Both teams, at the training scale and at a larger one (MIX does not depend on counts)."""
    env = pe_mjx.make(preset, backend="kinematic")
    policies = {
        t: pe_mjx.load_policy(SHIPPED, team=t, env_config=env.config) for t in ("pursuer", "evader")
    }

    def body(state, key):
        keys = jax.random.split(key)
        actions = {t: policies[t](state.obs[t], k) for t, k in zip(TEAMS, keys, strict=True)}
        allowed = jnp.stack(
            [
                jnp.all(jnp.take_along_axis(state.obs[t]["action_mask"], actions[t][:, None], 1))
                for t in actions
            ]
        )
        return env.step(state, actions), allowed

    @jax.jit
    def run(key):
        state = env.reset(key)
        return jax.lax.scan(body, state, jax.random.split(key, 20))

    final, allowed = run(jax.random.key(0))
    assert bool(allowed.all())
    assert int(final.world.step) == 20 or bool(final.done)


def test_shipped_policy_cannot_be_resumed():
    """It carries no optimiser state: resuming it is a clear error, not a library traceback."""
    from pe_mjx.ppo.run import saved_config

    with pytest.raises(CheckpointError, match="cannot be resumed"):
        saved_config(SHIPPED)


@pytest.fixture(scope="module")
def env_20_5_8():
    return pe_mjx.make("20-5-8", backend="kinematic")


@pytest.mark.parametrize("name", shipped_names())
def test_every_shipped_policy_loads_by_name_and_has_a_model_card(name, env_20_5_8):
    """Each shipped policy: valid metadata, a model card, and a valid action for every agent of
    each team it learned, loaded by its bare name (as `pe-mjx view/evaluate --pursuers NAME`)."""
    card = (SHIPPED.parent / "README.md").read_text()
    assert f"`{name}`" in card
    meta = read_meta(name)
    assert meta["network_configs"], name
    state = jax.jit(env_20_5_8.reset)(jax.random.key(1))
    for team in meta["network_configs"]:
        policy = pe_mjx.load_policy(name, team=team, env_config=env_20_5_8.config)
        action = policy(state.obs[team], jax.random.key(2))
        mask = state.obs[team]["action_mask"]
        assert action.shape == mask.shape[:1]
        assert bool(jnp.all(jnp.take_along_axis(mask, action[:, None], 1)))
