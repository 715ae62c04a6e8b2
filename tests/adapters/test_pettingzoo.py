"""The PettingZoo adapter, checked with PettingZoo's own API and seed tests."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from pe_mjx.adapters import OBSERVATION_KEYS, observation_layout
from pe_mjx.adapters.pettingzoo import PettingZooEnv
from pe_mjx.config import get_preset


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
    """Pursuers drive straight at full speed into the wall, one by one; the evader stands still."""
    cfg = get_preset("4-1-2")
    env = PettingZooEnv(cfg, backend="kinematic")
    p, e = cfg.pursuer, cfg.evader
    straight = {
        "pursuer": (p.num_speeds - 1) * p.num_turn_rates + p.num_turn_rates // 2,
        "evader": e.num_turn_rates // 2,  # v = 0, omega = 0
    }
    env.reset(seed=0)
    seen_partial = False
    for _ in range(cfg.max_steps):
        live = list(env.agents)
        actions = {a: straight[a.rsplit("_", 1)[0]] for a in live}
        obs, rewards, terminations, truncations, infos = env.step(actions)
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
