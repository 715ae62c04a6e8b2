"""Scripted and random policies: masked-valid actions, jit/vmap, and that the scripts play well.

Compiles are the cost here, so jitted policies are cached per (name, preset, team) and the three
play-strength matchups share one compiled rollout (the policy choice is a traced flag).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.match import rollout
from pe_mjx.names import TEAMS
from pe_mjx.policy.scripted import POLICIES, make_policy
from pe_mjx.stages.dynamics import action_table

VALIDITY_PRESET = "8-2-4"  # teammates, opponents and obstacles all present
MATCH_PRESET = "4-1-2"
ARENAS = 16
BUDGET = 200  # control steps per match in the play-strength tests


@functools.cache
def batched_policy(name: str, config: EnvConfig, team: str):
    """jit(vmap(policy)) over arenas, cached so tests share compiles."""
    return jax.jit(jax.vmap(make_policy(name, config, team)))


@jax.jit
def perturbed_obs(obs: dict, rng: jax.Array, valid_fraction: float | jax.Array) -> dict:
    """Batched team obs with random action masks (>= 1 valid per agent) and random g flags.

    Covers states a short rollout rarely reaches: downed teammates and opponents, every opponent
    down (a quarter of the arenas), and masks with a single valid action.
    """
    k_mask, k_one, k_flag_t, k_flag_o, k_all = jax.random.split(rng, 5)
    mask = obs["action_mask"]
    keep = jax.random.bernoulli(k_mask, valid_fraction, mask.shape)
    pick = jax.random.randint(k_one, mask.shape[:-1], 0, mask.shape[-1])
    mask = keep | jax.nn.one_hot(pick, mask.shape[-1], dtype=bool)

    def flags(key, x):
        return x.at[..., 0].set(jax.random.bernoulli(key, 0.3, x.shape[:-1]).astype(x.dtype))

    opponents = flags(k_flag_o, obs["opponents"])
    all_down = jax.random.bernoulli(k_all, 0.25, opponents.shape[:1])[:, None, None]
    opponents = opponents.at[..., 0].set(jnp.where(all_down, 1.0, opponents[..., 0]))
    teammates = flags(k_flag_t, obs["teammates"])
    return {**obs, "action_mask": mask, "teammates": teammates, "opponents": opponents}


@pytest.fixture(scope="module")
def reset_obs(get_compiled):
    """Team obs of 32 fresh arenas of VALIDITY_PRESET (kinematic)."""
    c = get_compiled(VALIDITY_PRESET, "kinematic")
    return c.batch_reset(jax.random.split(jax.random.key(7), 32)).obs


def chosen_valid(mask: jax.Array, actions: jax.Array) -> np.ndarray:
    """bool [...]: whether each agent's action is allowed by its mask [..., n_actions]."""
    return np.take_along_axis(np.asarray(mask), np.asarray(actions)[..., None], axis=-1)[..., 0]


def test_registry_names_and_errors():
    config = get_preset(MATCH_PRESET)
    assert set(POLICIES) == {"scripted", "random"}
    for name in POLICIES:
        for team in TEAMS:
            assert callable(make_policy(name, config, team))
    with pytest.raises(ValueError, match="scripted, random"):
        make_policy("greedy", config, "pursuer")
    for name in POLICIES:
        with pytest.raises(ValueError, match="team"):
            make_policy(name, config, "referee")


@pytest.mark.parametrize("team", TEAMS)
@pytest.mark.parametrize("name", ["scripted", "random"])
def test_actions_are_valid_under_jit_and_vmap(reset_obs, name, team):
    """Every chosen action is allowed by the mask, for real masks and sparse random ones."""
    config = get_preset(VALIDITY_PRESET)
    act = batched_policy(name, config, team)
    obs = reset_obs[team]
    n_arenas, n_agents, n_actions = obs["action_mask"].shape
    assert n_actions == config.team(team).num_actions
    cases = [obs] + [
        perturbed_obs(obs, jax.random.key(seed), fraction)
        for seed, fraction in ((1, 0.5), (2, 0.1), (3, 0.0))
    ]
    for i, case in enumerate(cases):
        actions = act(case, jax.random.split(jax.random.key(100 + i), n_arenas))
        assert actions.shape == (n_arenas, n_agents)
        assert actions.dtype == jnp.int32
        assert chosen_valid(case["action_mask"], actions).all(), f"masked action (case {i})"


@pytest.mark.parametrize("team", TEAMS)
def test_vmap_matches_single_arena(reset_obs, team):
    """vmap over arenas gives what each arena's own call gives (no cross-arena leakage)."""
    config = get_preset(VALIDITY_PRESET)
    obs = perturbed_obs(reset_obs[team], jax.random.key(5), 0.5)
    rngs = jax.random.split(jax.random.key(0), 32)
    batched = np.asarray(batched_policy("scripted", config, team)(obs, rngs))
    single = jax.jit(make_policy("scripted", config, team))
    for i in (0, 31):
        arena = jax.tree.map(lambda x, i=i: x[i], obs)
        np.testing.assert_array_equal(np.asarray(single(arena, rngs[i])), batched[i])


def test_random_policy_is_uniform_over_valid_actions(reset_obs):
    """Over many draws it hits every valid action, about equally often, and nothing else."""
    config = get_preset(VALIDITY_PRESET)
    obs = reset_obs["evader"]
    mask = np.zeros(obs["action_mask"].shape, dtype=bool)
    mask[..., 40:60] = True  # 20 valid actions for everyone
    obs = {**obs, "action_mask": jnp.asarray(mask)}
    act = batched_policy("random", config, "evader")
    draws = np.concatenate(
        [np.asarray(act(obs, jax.random.split(jax.random.key(s), 32))).ravel() for s in range(8)]
    )
    counts = np.bincount(draws, minlength=config.evader.num_actions)
    assert counts[:40].sum() == 0 and counts[60:].sum() == 0
    # 512 draws over 20 actions: ~25.6 each; every action drawn, none wildly over-represented.
    assert counts[40:60].min() > 5 and counts[40:60].max() < 60


def test_scripted_pursuer_stops_when_no_evader_is_active(reset_obs):
    config = get_preset(VALIDITY_PRESET)
    obs = reset_obs["pursuer"]
    obs = {**obs, "opponents": obs["opponents"].at[..., 0].set(1.0)}
    actions = batched_policy("scripted", config, "pursuer")(
        obs, jax.random.split(jax.random.key(0), 32)
    )
    speeds, _ = action_table(config.pursuer)
    assert (speeds[np.asarray(actions)] == 0).all()
    assert chosen_valid(obs["action_mask"], actions).all()


def test_single_agent_teams_without_obstacles(get_compiled):
    """Empty teammate and obstacle sets (T = 0, K = 0) work."""
    config = get_preset("2-1-1").with_counts(1, 1, 0)
    state = get_compiled(config, "kinematic").reset(0)
    for team in TEAMS:
        obs = state.obs[team]
        assert obs["teammates"].shape[1] == 0 and obs["obstacles"].shape[1] == 0
        for name in POLICIES:
            action = jax.jit(make_policy(name, config, team))(obs, jax.random.key(1))
            assert chosen_valid(obs["action_mask"], action).all()


# ----------------------------------------------------------------------------- play strength


def _either(flag: jax.Array, scripted, random):
    """A policy that acts like `scripted` where the traced bool `flag` is set, else `random`."""

    def policy(obs, rng):
        return jnp.where(flag, scripted(obs, rng), random(obs, rng))

    return policy


@pytest.fixture(scope="module")
def matches(get_compiled):
    """matches(pursuer, evader) -> metrics of ARENAS matches of BUDGET steps on MATCH_PRESET.

    Same arena draws for every matchup; one compile for all of them.
    """
    c = get_compiled(MATCH_PRESET, "kinematic")
    made = {(n, t): make_policy(n, c.config, t) for n in POLICIES for t in TEAMS}

    @jax.jit
    def run(keys, scripted_pursuer, scripted_evader):
        flags = {"pursuer": scripted_pursuer, "evader": scripted_evader}
        policies = {t: _either(flags[t], made["scripted", t], made["random", t]) for t in TEAMS}
        return jax.vmap(lambda k: rollout(c.env, policies, k, BUDGET))(keys).metrics

    @functools.cache
    def play(pursuer: str, evader: str):
        keys = jax.random.split(jax.random.key(2024), ARENAS)
        return jax.device_get(run(keys, pursuer == "scripted", evader == "scripted"))

    return play


def test_scripted_pursuers_capture_more_than_random_ones(matches):
    evaders = get_preset(MATCH_PRESET).evader.num_agents
    scripted = matches("scripted", "random")
    random = matches("random", "random")
    scripted_rate = scripted["episode/captures"].mean() / evaders
    random_rate = random["episode/captures"].mean() / evaders
    print(f"capture rate in {BUDGET} steps: scripted {scripted_rate:.3f}, random {random_rate:.3f}")
    assert scripted_rate >= 0.9
    assert scripted_rate - random_rate >= 0.3
    # And faster: the scripted pursuers end their episodes in well under half the time.
    assert scripted["episode/length"].mean() < 0.5 * random["episode/length"].mean()


def test_scripted_evader_outlives_random_evader(matches):
    vs_scripted = matches("scripted", "scripted")
    vs_random = matches("scripted", "random")
    scripted_life = vs_scripted["episode/length"].mean()
    random_life = vs_random["episode/length"].mean()
    print(
        f"evader survival in {BUDGET} steps: scripted {scripted_life:.1f}, random {random_life:.1f}"
    )
    assert scripted_life >= 2.5 * random_life
    # It survives by evading, not because the pursuers crash.
    assert vs_scripted["episode/pursuit_cost"].mean() <= 1.5
