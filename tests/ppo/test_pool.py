"""Opponent pools: off by default and then changing nothing, draws with the stated
probabilities, snapshots that play with their own parameters, every N iterations and the last M
kept, the co-evolving opponent learning only from its own arenas, metrics and evaluation per
member kind, an exact resume from a checkpoint, and both teams on pools at once."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.experiment import ExperimentConfig, PoolConfig
from pe_mjx.networks import sample_actions
from pe_mjx.policy.inference import normalize_obs
from pe_mjx.policy.store import CheckpointError
from pe_mjx.ppo import checkpoint
from pe_mjx.ppo.pool import Pool, PoolState, make_pools, settle
from pe_mjx.ppo.run import resolve_pool_members, warm_start
from pe_mjx.ppo.run_files import resume_config
from pe_mjx.ppo.train import Trainer
from tests.tiny_config import tiny

# MEAN encoders compile faster than the default MIX; the pool does not depend on the encoder.
MEAN = {"pursuer.network.encoder": "mean", "evader.network.encoder": "mean"}
POOL = {
    "pool.team": "pursuer",
    "pool.snapshot_every": 2,
    "pool.keep": 2,
    "pool.fixed": ["random"],
    "pool.p_current": 0.4,
    "pool.p_snapshots": 0.4,
    "pool.p_fixed": 0.2,
}
ITERATIONS = 5


def _max_diff(a, b) -> float:
    diffs = jax.tree.leaves(jax.tree.map(lambda x, y: jnp.max(jnp.abs(x - y)), a, b))
    return max((float(d) for d in diffs), default=0.0)


def _same(a, b) -> bool:
    """Every leaf equal, bit for bit (typed keys by their data)."""

    def data(x):
        is_key = jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)
        return np.asarray(jax.random.key_data(x) if is_key else x)

    pairs = zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    return all(np.array_equal(data(x), data(y), equal_nan=True) for x, y in pairs)


def _trained(**changes):
    """The trainer of the tiny config with `changes`, its jitted iteration, the state after each
    of `ITERATIONS` iterations (index 0: the initial one) and each iteration's metrics."""
    trainer = Trainer(tiny(**MEAN, **changes, env_steps=8 * 8 * ITERATIONS, eval_envs=8))
    step = jax.jit(trainer.iteration)
    states, metrics = [trainer.init()], []
    for _ in range(ITERATIONS):
        state, m = step(states[-1])
        states.append(state)
        metrics.append(jax.device_get(m))
    return trainer, step, states, metrics


@pytest.fixture(scope="module")
def pooled():
    """The pursuers against a pool (snapshots every 2 iterations, the last 2 kept, random as a
    fixed member), trained `ITERATIONS` iterations (`_trained`)."""
    return _trained(**POOL)


def test_the_pool_is_off_by_default_and_adds_no_state():
    assert ExperimentConfig().pool == PoolConfig() and not PoolConfig().on
    trainer = Trainer(tiny(**MEAN))
    assert trainer.pools == {} and trainer.abstract_state().pool is None
    # Configs saved before pools existed hold no "pool": they load with it off.
    saved = tiny(**MEAN).to_dict()
    del saved["pool"]
    assert ExperimentConfig.from_dict(saved).pool == PoolConfig()


def test_a_pool_of_the_current_opponent_alone_changes_no_number():
    """`p_current` 1: every arena plays the co-evolving opponent, and the run is bit for bit the
    run without a pool (the pool draws from its own random stream). That the pool-off path
    itself is unchanged was checked against the code before pools (docs/design.md)."""
    plain, pooled = Trainer(tiny(**MEAN)), Trainer(tiny(**MEAN, **{"pool.team": "evader"}))
    a, b = plain.init(), pooled.init()
    step_a, step_b = jax.jit(plain.iteration), jax.jit(pooled.iteration)
    for _ in range(2):
        (a, metrics_a), (b, metrics_b) = step_a(a), step_b(b)
    assert _max_diff(a.teams, b.teams) == 0.0
    assert _same(a.env_state, b.env_state) and _same(a.rng, b.rng)
    assert all(np.array_equal(metrics_a[k], metrics_b[k], equal_nan=True) for k in metrics_a)
    assert float(metrics_b["pool/vs_current/evader_reward"]) == pytest.approx(
        float(metrics_a["reward/evader/total"]), rel=1e-5
    )


def test_members_are_drawn_with_the_stated_probabilities():
    config = PoolConfig(
        team="pursuer",
        keep=4,
        fixed=("scripted", "random"),
        p_current=0.5,
        p_snapshots=0.3,
        p_fixed=0.2,
    )
    pool = make_pools(config, {"evader": None}, make_fixed=lambda name, _: name)["pursuer"]
    n = 200_000
    # 5 binomial standard deviations: a false failure has odds below 1e-6 per member.
    tol = 5 * np.sqrt(0.25 / n)
    # 3 snapshots taken (slots 1..3 of 4): 0.3 over 3; then 9 taken, all 4 slots kept.
    for count, snapshot in ((3, [0.1, 0.1, 0.1, 0.0]), (9, [0.075] * 4)):
        member = np.asarray(pool.draw(jax.random.key(count), jnp.int32(count), n))
        share = np.bincount(member, minlength=7) / n
        assert np.abs(share - [0.5, *snapshot, 0.1, 0.1]).max() < tol, share


def test_snapshots_are_taken_every_n_iterations_and_the_last_m_kept(pooled):
    _, _, states, _ = pooled
    # Taken at iterations 0, 2 and 4 (every 2); the ring of 2 keeps those of 2 (slot 1) and 4
    # (slot 0, over iteration 0's).
    assert [int(s.pool["pursuer"].count) for s in states] == [1, 1, 2, 2, 3, 3]
    last = states[-1].pool["pursuer"]
    for slot, iteration in ((0, 4), (1, 2)):
        evader = states[iteration].teams["evader"]
        kept = jax.tree.map(lambda x, s=slot: x[s], (last.params, last.normalizer))
        assert _max_diff(kept, (evader.params, evader.normalizer)) == 0.0


def test_a_warm_started_opponent_is_the_first_snapshot(pooled):
    trainer, _, states, _ = pooled
    evader = states[-1].teams["evader"]
    stored = {"params": evader.params, "normalizer": evader.normalizer}
    warm = warm_start(trainer, states[0], {"evader": stored})
    pool = warm.pool["pursuer"]
    assert int(pool.count) == 1
    for slot in range(trainer.config.pool.keep):
        kept = jax.tree.map(lambda x, s=slot: x[s], (pool.params, pool.normalizer))
        assert _max_diff(kept, (evader.params, evader.normalizer)) == 0.0


def test_a_snapshot_member_plays_with_its_own_parameters(pooled):
    trainer, _, states, _ = pooled
    state = states[-1]
    evader = state.teams["evader"]
    # Slot 1 (member 2) gets parameters of its own: the current ones with a policy that all but
    # always stops (action 0), where the current one is near uniform.
    bias = evader.params["params"]["policy_out"]["bias"]
    own = jax.tree.map(lambda x: x, evader.params)
    own["params"]["policy_out"]["bias"] = bias.at[0].add(30.0)
    before = state.pool["pursuer"]
    params = jax.tree.map(lambda s, x: s.at[1].set(x), before.params, own)
    pool = {"pursuer": before.replace(params=params, member=jnp.full_like(before.member, 2))}
    raw = state.env_state.obs
    obs = {t: trainer._inputs(t, raw[t]) for t in ("pursuer", "evader")}
    rng = jax.random.key(7)
    actions, _ = jax.jit(trainer._act)(state.teams, obs, rng, pool, raw)
    current, _ = jax.jit(trainer._act)(state.teams, obs, rng)
    normalizer = jax.tree.map(lambda x: x[1], before.normalizer)
    logits, _ = trainer.networks["evader"].apply(own, normalize_obs(obs["evader"], normalizer))
    evader_key = jax.random.split(rng, 2)[1]  # `_act` splits one key per team, in TEAMS order
    assert np.array_equal(actions["evader"], sample_actions(logits, evader_key))
    assert not np.array_equal(actions["evader"], current["evader"])
    assert np.array_equal(actions["pursuer"], current["pursuer"])  # the pool team as ever


def test_the_opponent_learns_only_where_its_current_policy_played(pooled):
    trainer, _, states, _ = pooled
    _, data = jax.jit(trainer._rollout)(states[2], jax.random.key(1))
    member = np.asarray(data["pool_member"]["pursuer"])  # [T, B]
    assert (member == 0).any() and (member != 0).any()
    evader_valid = np.asarray(data["evader"]["valid"]).any(axis=-1)
    assert not evader_valid[member != 0].any()
    assert np.asarray(data["pursuer"]["valid"]).any(axis=-1)[member != 0].any()


def test_metrics_and_evaluation_name_each_member_kind(pooled):
    trainer, _, states, metrics = pooled
    for kind in ("current", "snapshot", "random"):
        for name in ("episodes", "success_rate", "pursuer_reward"):
            assert all(f"pool/vs_{kind}/{name}" in m for m in metrics)
    shares = [
        sum(m[f"pool/vs_{k}/episodes"] for k in ("current", "snapshot", "random"))
        for m in metrics
        if m["episode/finished"] > 0
    ]
    assert shares and np.allclose(shares, 1.0)
    found = jax.jit(trainer.evaluate)(states[-1], jax.random.key(0))
    for pair in ("pursuer_vs_scripted", "evader_vs_scripted", "pursuer_vs_snapshot"):
        assert np.isfinite(float(found[f"eval/{pair}/success_rate"]))
    assert "eval/pursuer_vs_random/pursuer_return" in found


def test_the_pool_resumes_exactly_from_a_checkpoint(pooled, tmp_path):
    trainer, step, states, _ = pooled
    checkpoint.save(tmp_path, trainer, states[2])
    resumed = checkpoint.restore_train_state(tmp_path, trainer)
    assert _same(resumed.pool, states[2].pool)
    for _ in range(ITERATIONS - 2):
        resumed, _ = step(resumed)
    straight = states[-1]
    assert _max_diff(resumed.teams, straight.teams) == 0.0
    assert _same(resumed.pool, straight.pool) and _same(resumed.env_state, straight.env_state)
    # A trainer without a pool refuses the checkpoint in one line.
    with pytest.raises(checkpoint.CheckpointError, match="trained with an opponent pool"):
        checkpoint.restore_train_state(tmp_path, Trainer(tiny(**MEAN)))


@pytest.fixture(scope="module")
def both():
    """Both teams on pools (as `POOL`, p_current 0.4), trained `ITERATIONS` iterations."""
    return _trained(**{**POOL, "pool.team": "both"})


def test_settling_keeps_one_non_current_side_per_arena():
    """Where both pools drew a non-current member, a coin keeps one: every arena teaches at
    least one team, and each team meets a non-current member with probability q(1 + p)/2."""
    n, p = 200_000, 0.4
    keys = jax.random.split(jax.random.key(3), 3)

    def state(key, rng):
        member = jnp.where(jax.random.uniform(key, (n,)) < p, 0, 1).astype(jnp.int32)
        return PoolState(params=None, normalizer=None, count=jnp.int32(1), member=member, rng=rng)

    drawn = {"pursuer": state(keys[0], keys[2]), "evader": state(keys[1], keys[2])}
    settled = settle(drawn)
    pursuer, evader = (np.asarray(settled[t].member) for t in ("pursuer", "evader"))
    assert not ((pursuer != 0) & (evader != 0)).any()
    # Only conflicts change, and only to the current member.
    for team, member in (("pursuer", pursuer), ("evader", evader)):
        before = np.asarray(drawn[team].member)
        assert ((member == before) | (member == 0)).all()
    tol = 5 * np.sqrt(0.25 / n)
    for member in (pursuer, evader):
        assert abs(np.mean(member != 0) - (1 - p) * (1 + p) / 2) < tol
    assert settle({"pursuer": drawn["pursuer"]})["pursuer"] is drawn["pursuer"]


def test_both_teams_play_their_pools_and_learn_only_from_their_own_arenas(both):
    trainer, _, states, metrics = both
    assert set(trainer.pools) == {"pursuer", "evader"}
    assert all(isinstance(pool, Pool) for pool in trainer.pools.values())
    # Each pool holds the other team's snapshots.
    assert [int(s.pool["evader"].count) for s in states] == [1, 1, 2, 2, 3, 3]
    last = states[-1].pool["evader"]
    pursuer = states[4].teams["pursuer"]
    kept = jax.tree.map(lambda x: x[0], (last.params, last.normalizer))
    assert _max_diff(kept, (pursuer.params, pursuer.normalizer)) == 0.0
    _, data = jax.jit(trainer._rollout)(states[2], jax.random.key(1))
    member = {t: np.asarray(data["pool_member"][t]) for t in ("pursuer", "evader")}
    assert not ((member["pursuer"] != 0) & (member["evader"] != 0)).any()
    for pool_team, learner in (("pursuer", "evader"), ("evader", "pursuer")):
        stood_in = member[pool_team] != 0  # the learner's policy was replaced there
        assert stood_in.any()
        assert not np.asarray(data[learner]["valid"]).any(axis=-1)[stood_in].any()
    for team in ("pursuer", "evader"):
        for kind in ("current", "snapshot", "random"):
            assert all(f"pool/{team}_vs_{kind}/{team}_reward" in m for m in metrics)
    found = jax.jit(trainer.evaluate)(states[-1], jax.random.key(0))
    for pair in ("pursuer_vs_snapshot", "evader_vs_snapshot"):
        assert np.isfinite(float(found[f"eval/{pair}/success_rate"]))


def test_both_pools_resume_exactly_and_refuse_another_pool_team(both, tmp_path):
    trainer, step, states, _ = both
    checkpoint.save(tmp_path, trainer, states[2])
    resumed = checkpoint.restore_train_state(tmp_path, trainer)
    for _ in range(ITERATIONS - 2):
        resumed, _ = step(resumed)
    assert _max_diff(resumed.teams, states[-1].teams) == 0.0
    assert _same(resumed.pool, states[-1].pool)
    one = Trainer(tiny(**MEAN, **POOL, env_steps=8 * 8 * ITERATIONS))
    refused = r"pool\.team both\), this trainer has pool\.team pursuer"
    with pytest.raises(checkpoint.CheckpointError, match=refused):
        checkpoint.restore_train_state(tmp_path, one)


def test_resuming_cannot_switch_the_pool_on_or_off(tmp_path):
    plain, pooled = tiny(**MEAN), tiny(**MEAN, **POOL)
    for saved, requested in ((plain, pooled), (pooled, plain)):
        with pytest.raises(ValueError, match=r"cannot change pool\.") as err:
            resume_config(tmp_path, requested, saved)
        assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("changes", "needle"),
    [
        ({"pool.team": "pursuer", "pool.p_current": 0.5}, "sum to 1"),
        ({"pool.team": "pursuer", "pool.p_current": -0.5, "pool.p_snapshots": 1.5}, ">= 0"),
        ({"pool.keep": 0}, "pool.keep must be >= 1"),
        ({"pool.snapshot_every": 0}, "pool.snapshot_every must be >= 1"),
        ({"pool.fixed": ["learn"], "pool.p_current": 0.5, "pool.p_fixed": 0.5}, "pool.fixed"),
        (
            {"pool.fixed": ["runs/a/mix", "other/mix"], "pool.p_current": 0.5, "pool.p_fixed": 0.5},
            "one last path part",
        ),
        ({"pool.fixed": ["snapshot"], "pool.p_current": 0.5, "pool.p_fixed": 0.5}, "pool.fixed"),
        ({"pool.fixed": ["random"]}, "pool.p_fixed must be > 0"),
        ({"pool.team": "pursuer", "evader.policy": "scripted"}, "needs both teams learning"),
        ({"pool.team": "referee"}, "pool.team"),
    ],
)
def test_bad_pool_settings_are_one_line(changes, needle):
    with pytest.raises(ValueError, match=needle) as err:
        tiny(**changes)
    assert "\n" not in str(err.value)


SHIPPED_MEMBER = {
    "pool.team": "pursuer",
    "pool.fixed": ["mean-20-5-8-3m"],
    "pool.p_current": 0.5,
    "pool.p_fixed": 0.5,
}


def test_a_shipped_fixed_member_plays_its_own_actions_in_its_arenas():
    """A learned fixed member (a shipped policy, resolved for the opponent team at this scene)
    gives the arenas that drew it its own actions, is named by its policy in the metrics and
    meets the pool team in the in-training evaluation."""
    config = tiny(**MEAN, **SHIPPED_MEMBER, eval_envs=8)
    members = resolve_pool_members(config)
    assert list(members) == [("evader", "mean-20-5-8-3m")]
    member = members["evader", "mean-20-5-8-3m"]
    assert member.learned and member.team == "evader"
    with pytest.raises(ValueError, match="must be handed in as a pool member"):
        Trainer(config)  # a learned member is resolved by the caller, never guessed
    trainer = Trainer(config, pool_members=members)
    assert trainer.pools["pursuer"].kinds == ("current", "snapshot", "mean-20-5-8-3m")
    state = trainer.init()
    before = state.pool["pursuer"]
    pool = {"pursuer": before.replace(member=jnp.full_like(before.member, 1 + config.pool.keep))}
    raw = state.env_state.obs
    obs = {t: trainer._inputs(t, raw[t]) for t in ("pursuer", "evader")}
    rng = jax.random.key(3)
    actions, _ = jax.jit(trainer._act)(state.teams, obs, rng, pool, raw)
    current, _ = jax.jit(trainer._act)(state.teams, obs, rng)
    evader_key = jax.random.split(rng, 2)[1]  # `_act` splits one key per team, in TEAMS order
    keys = jax.random.split(jax.random.fold_in(evader_key, 1), before.member.shape[0])
    assert np.array_equal(actions["evader"], jax.vmap(member)(raw["evader"], keys))
    assert not np.array_equal(actions["evader"], current["evader"])
    assert np.array_equal(actions["pursuer"], current["pursuer"])
    found = jax.jit(trainer.evaluate)(state, jax.random.key(0))
    assert np.isfinite(float(found["eval/pursuer_vs_mean-20-5-8-3m/success_rate"]))


@pytest.mark.parametrize("spec", ["no-such-policy", "tests"])
def test_a_fixed_member_that_cannot_play_is_one_line_naming_the_flag(spec):
    config = tiny(**MEAN, **{**SHIPPED_MEMBER, "pool.fixed": [spec]})
    with pytest.raises(CheckpointError, match=r"^--pool\.fixed: ") as err:
        resolve_pool_members(config)
    assert "\n" not in str(err.value)
