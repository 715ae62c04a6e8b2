"""The JaxMARL adapter, run through JaxMARL's own base class, `LogWrapper` and `CTRolloutManager`.

One jitted `lax.scan` over a vmapped batch carries every check of the auto-reset path, so the
file compiles the env step about twice.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxmarl.environments.multi_agent_env import MultiAgentEnv
from jaxmarl.wrappers.baselines import CTRolloutManager, LogWrapper

from pe_mjx.adapters.common import flatten_observation
from pe_mjx.adapters.jaxmarl import JaxMARLEnv
from pe_mjx.config import get_preset
from pe_mjx.names import TEAMS
from pe_mjx.stages.dynamics import action_table

BATCH, STEPS, MAX_STEPS = 4, 20, 7


def test_spaces_follow_the_config_at_the_paper_preset():
    env = JaxMARLEnv("20-5-8", backend="kinematic")
    assert isinstance(env, MultiAgentEnv)
    assert env.num_agents == len(env.agents) == 25
    assert env.agents[:2] == ["pursuer_0", "pursuer_1"] and env.agents[20] == "evader_0"
    assert env.action_space("pursuer_19").n == 39 and env.action_space("evader_4").n == 95
    assert env.agent_classes["evader"] == [f"evader_{i}" for i in range(5)]
    sizes = {a: env.observation_space(a).shape for a in env.agents}
    assert sizes["pursuer_0"] == (5 + 6 * 19 + 6 * 5 + 4 * 8 + 19 + 5 + 8,)
    assert sizes["evader_0"] == (5 + 6 * 4 + 6 * 20 + 4 * 8 + 4 + 20 + 8,)


def _rollout():
    """LogWrapper(JaxMARLEnv) on 2-1-1 with max_steps 7: [STEPS] vmapped masked-random steps."""
    base = JaxMARLEnv(get_preset("2-1-1").replace(max_steps=MAX_STEPS), backend="kinematic")
    env = LogWrapper(base)

    def body(carry, rng):
        obs, state = carry
        act_rng, step_rng = jax.random.split(rng)
        avail = jax.vmap(base.get_avail_actions)(state.env_state)
        actions = {}
        for agent, r in zip(base.agents, jax.random.split(act_rng, base.num_agents), strict=True):
            logits = jnp.where(avail[agent], 0.0, -jnp.inf)
            actions[agent] = jax.random.categorical(r, logits)  # [BATCH]
        # The env's own step on the same state: the adapter must change nothing but the layout.
        team_actions = {
            t: jnp.stack([actions[a] for a in base.team_agents[t]], axis=1) for t in TEAMS
        }
        direct = jax.vmap(base.env.step)(state.env_state, team_actions)
        obs, state, reward, done, info = jax.vmap(env.step)(
            jax.random.split(step_rng, BATCH), state, actions
        )
        out = {
            "obs": obs,
            "reward": reward,
            "done": done,
            "info": info,
            "avail_taken": {
                a: jnp.take_along_axis(avail[a], actions[a][:, None], 1)[:, 0] for a in base.agents
            },
            "direct_reward": direct.reward,
            "direct_obs": {t: jax.vmap(flatten_observation)(direct.obs[t]) for t in TEAMS},
            "direct_active": base.env.active(direct),
            "step_after": state.env_state.world.step,
        }
        return (obs, state), out

    @jax.jit
    def run(rng):
        reset_rng, scan_rng = jax.random.split(rng)
        obs, state = jax.vmap(env.reset)(jax.random.split(reset_rng, BATCH))
        _, out = jax.lax.scan(body, (obs, state), jax.random.split(scan_rng, STEPS))
        return obs, out

    return base, jax.device_get(run(jax.random.key(0)))


def test_log_wrapper_auto_reset_and_returns_match_the_env():
    base, (first_obs, out) = _rollout()
    done_all = out["done"]["__all__"]  # [STEPS, BATCH]
    assert done_all.any(axis=0).all(), "every arena must finish an episode within the rollout"
    for agent in base.agents:
        assert out["avail_taken"][agent].all()
    # The adapter's rewards, obs and dones are the env's own, split per agent (up to float32
    # rounding: XLA fuses the two copies of the step differently).
    for t in TEAMS:
        for i, agent in enumerate(base.team_agents[t]):
            np.testing.assert_allclose(
                out["reward"][agent], out["direct_reward"][t][:, :, i], rtol=1e-5, atol=1e-5
            )
            down = ~out["direct_active"][t][:, :, i]
            np.testing.assert_array_equal(out["done"][agent], down | done_all)
            live = ~done_all  # on done steps the obs are the next episode's first
            np.testing.assert_allclose(
                out["obs"][agent][live], out["direct_obs"][t][:, :, i][live], atol=1e-5
            )
    # Auto-reset: a finished arena starts over at step 0 with a fresh draw.
    np.testing.assert_array_equal(out["step_after"] == 0, done_all)
    first_reset = out["obs"]["pursuer_0"][done_all.argmax(axis=0), np.arange(BATCH)]
    assert not np.allclose(first_reset, first_obs["pursuer_0"])
    # LogWrapper's returns are the per-agent reward sums of each finished episode.
    returns = out["info"]["returned_episode_returns"]  # [STEPS, BATCH, N]
    lengths = out["info"]["returned_episode_lengths"]
    rewards = np.stack([out["reward"][a] for a in base.agents], axis=-1)
    for b in range(BATCH):
        start, checked = 0, 0
        for s in np.flatnonzero(done_all[:, b]):
            np.testing.assert_allclose(returns[s, b], rewards[start : s + 1, b].sum(0), rtol=1e-5)
            assert (lengths[s, b] == s + 1 - start).all() and s + 1 - start <= MAX_STEPS
            start, checked = s + 1, checked + 1
        assert checked >= 1
    # An agent that is down earns nothing until its episode ends.
    done_agents = np.stack([out["done"][a] for a in base.agents], axis=-1)
    after_down = np.zeros_like(done_agents)
    after_down[1:] = done_agents[:-1] & ~done_all[:-1, :, None]
    assert (rewards[after_down] == 0).all()
    assert out["info"]["active"].shape == out["info"]["truncation"].shape == (STEPS, BATCH, 3)


def test_ct_rollout_manager_batches_pads_and_steps():
    """JaxMARL's Q-learning wrapper: pads obs to one length, adds ids and a global state."""
    base = JaxMARLEnv("2-1-1", backend="kinematic")
    manager = CTRolloutManager(base, batch_size=3)
    obs, state = manager.batch_reset(jax.random.key(0))
    width = max(base.observation_space(a).shape[0] for a in base.agents) + base.num_agents
    assert all(obs[a].shape == (3, width) for a in base.agents)
    actions = {a: manager.batch_sample(jax.random.key(i), a) for i, a in enumerate(base.agents)}
    obs, state, reward, done, _ = manager.batch_step(jax.random.key(9), state, actions)
    assert reward["__all__"].shape == (3,)
    np.testing.assert_allclose(
        reward["__all__"], sum(np.asarray(reward[a]) for a in base.agents), rtol=1e-6
    )
    expected_steps = np.where(np.asarray(done["__all__"]), 0, 1)  # auto-reset if it ended
    np.testing.assert_array_equal(state.world.step, expected_steps)
    assert obs["__all__"].shape == (3, sum(base.observation_space(a).shape[0] for a in base.agents))


def test_invalid_actions_follow_jaxmarls_convention():
    """No raise inside `step` (JaxMARL steps under jit and vmap): an index out of range (999,
    -1) or one that `get_avail_actions` forbids is played as the stop action and marked in
    infos["invalid_action"]; the rest of the step is the env's. What is static (agent names, the
    dtype) is a ValueError when `step` is traced."""
    base = JaxMARLEnv(get_preset("4-2-2"), backend="kinematic")
    # Some agent has an action its mask forbids (4-2-2's pursuers always do: the minimum turning
    # radius).
    _, state = base.reset(jax.random.key(1))
    avail = jax.device_get(base.get_avail_actions(state))
    forbidden = {a: np.flatnonzero(~avail[a]) for a in base.agents}
    masked_agent = next(a for a in base.agents if forbidden[a].size)
    valid = {a: int(np.flatnonzero(avail[a])[-1]) for a in base.agents}
    actions = {
        **valid,
        "pursuer_1": 999,
        "pursuer_2": -1,
        masked_agent: int(forbidden[masked_agent][0]),
    }
    step = jax.jit(base.step_env)
    _, new, _, _, infos = step(
        jax.random.key(0), state, {a: jnp.int32(x) for a, x in actions.items()}
    )
    flagged = {
        a for a, f in zip(base.agents, np.asarray(infos["invalid_action"]), strict=True) if f
    }
    assert flagged == {"pursuer_1", "pursuer_2", masked_agent}
    played = {
        t: jnp.array(
            [base.noop[t] if a in flagged else actions[a] for a in base.team_agents[t]], jnp.int32
        )
        for t in TEAMS
    }
    direct = base.env.step(state, played)
    np.testing.assert_array_equal(np.asarray(new.world.pos), np.asarray(direct.world.pos))
    v, omega = action_table(base.env.config.pursuer)
    assert (
        v[base.noop["pursuer"]] == 0
        and abs(omega[base.noop["pursuer"]]) == np.abs(omega[v == 0]).min()
    )
    # All valid: nothing flagged.
    _, _, _, _, infos = step(jax.random.key(0), state, {a: jnp.int32(x) for a, x in valid.items()})
    assert not np.asarray(infos["invalid_action"]).any()
    with pytest.raises(ValueError, match=r"unknown agents \['referee'\]"):
        base.step_env(jax.random.key(0), state, {**valid, "referee": 0})
    with pytest.raises(ValueError, match=r"no action for agents \['evader_0'\]"):
        base.step_env(jax.random.key(0), state, {a: x for a, x in valid.items() if a != "evader_0"})
    with pytest.raises(ValueError, match=r"pursuer_0: actions must be integer indices .*float32"):
        base.step_env(jax.random.key(0), state, {**valid, "pursuer_0": jnp.float32(1.7)})
