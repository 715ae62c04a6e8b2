"""play_episodes: every path plays rollout's episode, and returns sum each agent's rewards."""

from __future__ import annotations

import jax
import numpy as np

from pe_mjx import get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.episodes import play_episodes
from pe_mjx.names import TEAMS
from pe_mjx.policy.scripted import make_policy


def test_returns_sum_each_agents_rewards_over_its_episode():
    config = get_preset("2-1-1").replace(max_steps=100)
    env = PursuitEvasionEnv(config, backend="kinematic")
    policies = {"pursuer": make_policy("scripted", config, "pursuer")}
    policies["evader"] = make_policy("random", config, "evader")
    keys = jax.random.split(jax.random.key(3), 4)

    @jax.jit
    def play(keys):
        return (
            play_episodes(env, policies, keys),
            play_episodes(env, policies, keys, returns=True),
            play_episodes(env, policies, keys, record=True, returns=True),
        )

    plain, (final, returns), (recorded, _, recorded_returns) = play(keys)

    @jax.jit
    def step(s, key):  # match.rollout's key splits
        key, *team_keys = jax.random.split(key, len(TEAMS) + 1)
        actions = {t: policies[t](s.obs[t], k) for t, k in zip(TEAMS, team_keys, strict=True)}
        return env.step(s, actions), key

    lengths = []
    for i, key in enumerate(keys):
        rng, reset_rng = jax.random.split(key)
        s = env.reset(reset_rng)
        expected = {t: np.zeros(s.reward[t].shape) for t in TEAMS}
        while not int(s.done):
            s, rng = step(s, rng)
            for t in TEAMS:
                expected[t] += np.asarray(s.reward[t])
        lengths.append(int(s.world.step))
        for batch in (plain, final, recorded):
            assert int(batch.world.step[i]) == int(s.world.step)
        for t in TEAMS:
            np.testing.assert_allclose(np.asarray(returns[t][i]), expected[t], rtol=1e-5)
            np.testing.assert_allclose(np.asarray(recorded_returns[t][i]), expected[t], rtol=1e-5)
    # Arenas that ended early froze while the others played on.
    assert min(lengths) < config.max_steps, lengths
    assert returns["pursuer"].shape == (4, 2) and returns["evader"].shape == (4, 1)
