"""The PettingZoo adapter, checked with PettingZoo's own API and seed tests."""

from __future__ import annotations

import warnings

import jax
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from pe_mjx.adapters import OBSERVATION_KEYS, observation_layout
from pe_mjx.adapters.pettingzoo import PettingZooEnv
from pe_mjx.config import get_preset
from pe_mjx.policy.scripted import make_policy
from pe_mjx.stages.dynamics import action_table
from pe_mjx.stages.masks import stop_actions


def test_parallel_api_test_passes_without_warnings():
    env = PettingZooEnv("2-1-1", backend="kinematic")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parallel_api_test(env, num_cycles=1000)
    from_pettingzoo = [str(w.message) for w in caught if "pettingzoo" in w.filename]
    assert from_pettingzoo == []


def test_parallel_seed_test_passes():
    parallel_seed_test(lambda: PettingZooEnv("2-1-1", backend="kinematic"))


@pytest.mark.parametrize("preset", ["16-4-4", "20-5-8", "24-6-12"])
def test_paper_presets_have_the_papers_action_counts_and_documented_sizes(preset):
    cfg = get_preset(preset)
    env = PettingZooEnv(preset, backend="kinematic")
    p, e, k = cfg.pursuer.num_agents, cfg.evader.num_agents, cfg.arena.num_obstacles
    assert env.possible_agents == [f"pursuer_{i}" for i in range(p)] + [
        f"evader_{i}" for i in range(e)
    ]
    assert env.action_space("pursuer_0").n == cfg.pursuer.num_actions == 39
    assert env.action_space(f"evader_{e - 1}").n == cfg.evader.num_actions == 95
    # own 5, six features per teammate and opponent, four per obstacle, then one 0/1 per entity.
    sizes = {"pursuer": 5 + 6 * (p - 1) + 6 * e + 4 * k, "evader": 5 + 6 * (e - 1) + 6 * p + 4 * k}
    for team, size in sizes.items():
        n_entities = (p + e - 1) + k
        space = env.observation_space(f"{team}_0")
        assert space["observation"].shape == (size + n_entities,)
        assert space["action_mask"].shape == (cfg.team(team).num_actions,)
        assert list(env.observation_layout(f"{team}_0")) == list(OBSERVATION_KEYS)


def test_observations_are_the_envs_flattened_with_its_action_mask():
    env = PettingZooEnv("4-1-2", backend="kinematic")
    obs, infos = env.reset(seed=3)
    assert set(obs) == set(infos) == set(env.possible_agents)
    state = env.pe_state
    for agent in env.possible_agents:
        team, i = agent.rsplit("_", 1)
        i = int(i)
        assert env.observation_space(agent).contains(obs[agent])
        vector = obs[agent]["observation"]
        for key, (sl, shape) in observation_layout(env.env, team).items():
            expected = np.asarray(state.obs[team][key][i], np.float32)
            np.testing.assert_array_equal(vector[sl].reshape(shape), expected, err_msg=key)
        mask = np.asarray(state.obs[team]["action_mask"][i])
        np.testing.assert_array_equal(obs[agent]["action_mask"], mask.astype(np.int8))
        assert mask.any()


def test_downed_agents_leave_agents_and_the_rest_play_on():
    """Scripted pursuers against evaders that stand still, valid actions only: the first capture
    downs one evader (and its captor) while the rest play on, until the episode ends."""
    cfg = get_preset("4-2-2")
    env = PettingZooEnv(cfg, backend="kinematic")
    scripted = jax.jit(make_policy("scripted", cfg, "pursuer"))
    _, omega = action_table(cfg.evader)
    still = int(np.argmin(np.where(stop_actions(cfg.evader), np.abs(omega), np.inf)))

    def policies(obs, step):
        chosen = np.asarray(scripted(env.pe_state.obs["pursuer"], jax.random.key(step)))
        actions = {}
        for agent in env.agents:
            team, i = agent.rsplit("_", 1)
            mask = obs[agent]["action_mask"]
            if team == "pursuer":
                actions[agent] = int(chosen[int(i)])
            else:
                actions[agent] = still if mask[still] else int(np.flatnonzero(mask)[0])
        return actions

    obs, _ = env.reset(seed=0)
    seen_partial = False
    for step in range(cfg.max_steps):
        live = list(env.agents)
        obs, rewards, terminations, truncations, infos = env.step(policies(obs, step))
        assert set(infos) == set(live)
        assert set(obs) == set(rewards) == set(terminations) == set(truncations) == set(live)
        active = env.env.active(env.pe_state)
        episode_over = bool(env.pe_state.done)
        for agent in live:
            team, i = agent.rsplit("_", 1)
            down = not bool(active[team][int(i)])
            assert terminations[agent] == (down or bool(env.pe_state.info["terminated"]))
            assert (agent in env.agents) == (not down and not episode_over)
        seen_partial |= 0 < len(env.agents) < len(live)
        if not env.agents:
            break
    assert not env.agents, "the episode never ended"
    assert seen_partial, "no step downed some agents while others played on"


def test_invalid_actions_are_refused_before_anything_is_stepped():
    """Out of range (999 was clamped, -1 wrapped), not an integer (1.7 was truncated), masked by
    the agent's own action_mask, or for an unknown agent: a ValueError naming the agent, and the
    state is left as it was."""
    cfg = get_preset("4-2-2")  # pursuers with a minimum turning radius: some actions masked
    env = PettingZooEnv(cfg, backend="kinematic")
    # The first seed where some agent starts with an action its mask forbids (near the wall or
    # an obstacle, or turning tighter than allowed).
    for seed in range(100):
        obs, _ = env.reset(seed=seed)
        limited = [a for a in env.agents if not obs[a]["action_mask"].all()]
        if limited:
            break
    agent = limited[0]
    valid = {a: int(np.flatnonzero(obs[a]["action_mask"])[0]) for a in env.agents}
    masked = int(np.flatnonzero(obs[agent]["action_mask"] == 0)[0])
    n = env.action_space("pursuer_0").n
    before = env.pe_state
    cases = [
        ({"pursuer_0": 999}, rf"pursuer_0: action 999 is out of range \[0, {n}\)"),
        ({"pursuer_0": -1}, rf"pursuer_0: action -1 is out of range \[0, {n}\)"),
        ({"pursuer_0": n}, "out of range"),
        ({"pursuer_0": 1.7}, r"pursuer_0: the action must be an integer index .*1\.7"),
        ({"pursuer_0": 2.0}, "must be an integer index"),
        ({"pursuer_0": True}, "must be an integer index"),
        ({"pursuer_0": "3"}, "must be an integer index"),
        ({"pursuer_0": np.array([1, 2])}, r"array of shape \(2,\)"),
        ({agent: masked}, rf"{agent}: action {masked} is not allowed by its action_mask"),
        ({"referee_0": 0}, r"unknown agents \['referee_0'\]"),
    ]
    for change, message in cases:
        with pytest.raises(ValueError, match=message):
            env.step({**valid, **change})
        assert env.pe_state is before, change
    # numpy and 0-d integers are indices like ints.
    env.step({**valid, "pursuer_0": np.int64(valid["pursuer_0"])})
    assert env.pe_state is not before
