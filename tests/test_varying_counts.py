"""Entity counts drawn per episode (`TeamConfig.min_agents`, `ArenaConfig.min_obstacles`): the
absent agents and obstacles keep every rule. On both backends, B arenas play T random valid steps
with auto-reset (fresh draws of the counts); after every step an absent agent is inactive with
cause ABSENT, has not moved, is far from everything, earns no reward, and is masked out of every
observation; absent obstacles are masked too; and the outcome counts only the agents present.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.env import AutoResetWrapper, PursuitEvasionEnv
from pe_mjx.names import ABSENT, TEAMS
from pe_mjx.outcomes import outcome_counts
from pe_mjx.stages.geometry import drop_diagonal
from pe_mjx.stages.placement import draw_counts

B, T = 16, 60


def varying(preset: str = "8-2-4"):
    base = get_preset(preset)
    return base.replace(
        max_steps=25,  # short episodes: many resets, many draws of the counts
        pursuer=dataclasses.replace(base.pursuer, min_agents=3),
        evader=dataclasses.replace(base.evader, min_agents=1),
        arena=dataclasses.replace(base.arena, min_obstacles=1),
    )


def step_checks(env: PursuitEvasionEnv, before, after) -> dict[str, jax.Array]:
    """Rule breaks of absent entities in one step of one arena (`after` before any reset)."""
    w0, w1 = before.world, after.world
    absent = w0.cause == ABSENT
    present = ~absent
    far = jnp.linalg.norm(w1.pos, axis=-1) > 5 * env.config.arena.radius
    gaps = jnp.linalg.norm(w1.pos[:, None] - w1.pos[None, :], axis=-1)
    near_absent = jnp.any(present[:, None] & absent[None, :] & (gaps < 10.0))
    seen_absent = jnp.zeros((), jnp.int32)
    mask_errors = jnp.zeros((), jnp.int32)
    reward = jnp.zeros(())
    split = env.split(absent)
    for team in TEAMS:
        obs = before.obs[team]
        s = env.team_slices[team]
        other = env.team_slices["evader" if team == "pursuer" else "pursuer"]
        want_mates = drop_diagonal(jnp.broadcast_to(~absent[s][None, :], (s.stop - s.start,) * 2))
        want_opps = jnp.broadcast_to(~absent[other][None, :], obs["opponent_mask"].shape)
        want_obst = jnp.broadcast_to((w0.obstacles[:, 2] > 0)[None, :], obs["obstacle_mask"].shape)
        mask_errors += jnp.sum(obs["teammate_mask"] != want_mates)
        mask_errors += jnp.sum(obs["opponent_mask"] != want_opps)
        mask_errors += jnp.sum(obs["obstacle_mask"] != want_obst)
        seen_absent += jnp.sum(obs["opponent_mask"] & ~want_opps)
        reward += jnp.sum(jnp.abs(jnp.where(split[team], after.reward[team], 0.0)))
        seen_absent += jnp.sum(after.info["valid"][team] & split[team])
    return {
        "absent": jnp.sum(absent),
        "absent_obstacles": jnp.sum(w0.obstacles[:, 2] == 0),
        "absent_active": jnp.sum(absent & (w1.active | (w1.cause != ABSENT))),
        "absent_moved": jnp.sum(absent & (jnp.any(w1.pos != w0.pos, -1) | (w1.yaw != w0.yaw))),
        "absent_near": jnp.sum(absent & ~far) + near_absent,
        "absent_seen": seen_absent,
        "mask_errors": mask_errors,
        "absent_reward": reward,
        "pursuers_present": jnp.sum(present[: env.num_pursuers]),
        "evaders_present": jnp.sum(present[env.num_pursuers :]),
    }


@pytest.fixture(scope="module", params=("kinematic", "mjx"))
def played(request):
    env = PursuitEvasionEnv(varying(), backend=request.param)
    auto = AutoResetWrapper(env)

    @jax.jit
    def run(key):
        state = jax.vmap(env.reset)(jax.random.split(key, B))

        def body(s, k):
            actions = {}
            for kt, t in zip(jax.random.split(k), TEAMS, strict=True):
                mask = s.obs[t]["action_mask"]
                actions[t] = jax.random.categorical(kt, jnp.where(mask, 0.0, -jnp.inf))
            raw = jax.vmap(env.step)(s, actions)
            checks = jax.vmap(lambda a, b: step_checks(env, a, b))(s, raw)
            counts = outcome_counts(raw.world.cause, raw.world.distance, env.num_pursuers)
            checks["success_rate"] = counts["success_rate"]
            checks["metric_success"] = raw.metrics["episode/success_rate"]
            checks["evaders_down"] = counts["evaders_incapacitated"]
            return auto.step_batch(s, actions), checks

        return jax.lax.scan(body, state, jax.random.split(key, T))[1]

    return request.param, jax.device_get(run(jax.random.key(0)))


def test_absent_agents_never_move_collide_observe_or_earn(played):
    backend, checks = played
    assert int(np.sum(checks["absent"])) > B * T  # many absent agent-steps were checked
    assert int(np.sum(checks["absent_obstacles"])) > 0
    for key in ("absent_active", "absent_moved", "absent_near", "absent_seen", "mask_errors"):
        assert int(np.sum(checks[key])) == 0, (backend, key)
    assert float(np.sum(checks["absent_reward"])) == 0.0


def test_counts_are_drawn_per_episode_within_their_ranges(played):
    _, checks = played
    p, e = checks["pursuers_present"], checks["evaders_present"]
    assert p.min() >= 3 and p.max() <= 8 and e.min() >= 1 and e.max() <= 2
    assert len(np.unique(p)) >= 4 and len(np.unique(e)) == 2  # resets draw new counts


def test_outcomes_count_only_the_agents_present(played):
    _, checks = played
    rate, down, present = checks["success_rate"], checks["evaders_down"], checks["evaders_present"]
    np.testing.assert_array_equal(rate, down / present)
    np.testing.assert_allclose(checks["metric_success"], rate, rtol=1e-6)
    assert rate.max() <= 1.0


def test_the_counts_keep_the_minimum_of_each_team_and_the_arena():
    for seed in range(20):
        present, obstacles = draw_counts(varying(), jax.random.key(seed))
        assert int(present[:8].sum()) >= 3 and int(present[8:].sum()) >= 1
        assert int(obstacles.sum()) >= 1
        # the first n of each team take part
        assert bool(jnp.all(present[:8] == (jnp.arange(8) < present[:8].sum())))
    assert present.shape == (10,) and obstacles.shape == (4,)


def test_a_bad_range_is_one_clear_error():
    base = get_preset("8-2-4")
    with pytest.raises(ValueError, match="min_agents"):
        base.replace(pursuer=dataclasses.replace(base.pursuer, min_agents=9))
    with pytest.raises(ValueError, match="min_obstacles"):
        base.replace(arena=dataclasses.replace(base.arena, min_obstacles=5))
