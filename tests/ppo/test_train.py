"""IPPO co-evolution: it learns, it is deterministic, resumes exactly, and scales over devices."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.episodes import play_episodes
from pe_mjx.experiment import default_config
from pe_mjx.policy.scripted import make_policy
from pe_mjx.ppo.train import Trainer
from tests.tiny_config import tiny


def params_close(a, b, atol=0.0) -> bool:
    leaves = jax.tree.leaves(jax.tree.map(lambda x, y: jnp.max(jnp.abs(x - y)), a, b))
    return max(float(x) for x in leaves) <= atol


def test_iteration_updates_both_teams_and_reports_every_term():
    trainer = Trainer(tiny())
    state = trainer.init()
    before = jax.tree.map(np.asarray, state.teams)
    # Donating, as the training loop does, so that this program is shared with test_checkpoint's.
    step = jax.jit(trainer.iteration, donate_argnums=0)
    new, metrics = step(state)
    for team in ("pursuer", "evader"):
        assert not params_close(before[team].params, new.teams[team].params)
        for name in ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction"):
            assert np.isfinite(float(metrics[f"loss/{team}/{name}"]))
    for term in ("wall", "obstacle", "teammate", "pursuit", "capture", "opponent"):
        assert f"reward/pursuer/{term}" in metrics
    for term in ("wall", "obstacle", "teammate", "opponent", "alive"):
        assert f"reward/evader/{term}" in metrics
    assert "episode/success_rate" in metrics
    assert int(new.env_steps) == 64
    # Same seed, same result.
    again, _ = step(trainer.init())
    assert params_close(again.teams["pursuer"].params, new.teams["pursuer"].params)


def test_fixed_opponent_is_not_trained():
    trainer = Trainer(tiny(**{"evader.policy": "scripted", "pursuer.network.encoder": "mean"}))
    assert trainer.learned == ("pursuer",)
    state = trainer.init()
    new, metrics = jax.jit(trainer.iteration)(state)
    assert "evader" not in new.teams
    assert "loss/pursuer/entropy" in metrics and "loss/evader/entropy" not in metrics


def test_a_critic_warmup_moves_only_the_value_head_until_it_ends():
    """`critic_warmup` 1: the first iteration changes the pursuer's value head alone (policy
    head and shared encoder exactly as they were); the second changes every part."""
    trainer = Trainer(tiny(**{"evader.policy": "scripted", "pursuer.critic_warmup": 1}))
    step = jax.jit(trainer.iteration)

    def moved(before, after):
        """Each top-level module of the network: whether any of its parameters changed."""
        return {
            name: any(
                bool(np.any(x != y))
                for x, y in zip(
                    jax.tree.leaves(before["params"][name]),
                    jax.tree.leaves(after["params"][name]),
                    strict=True,
                )
            )
            for name in before["params"]
        }

    state0 = trainer.init()
    params0 = jax.device_get(state0.teams["pursuer"].params)
    state1, _ = step(state0)
    params1 = jax.device_get(state1.teams["pursuer"].params)
    first = moved(params0, params1)
    assert {n for n, m in first.items() if m} == {"value_hidden_0", "value_hidden_1", "value_out"}
    state2, _ = step(state1)
    second = moved(params1, jax.device_get(state2.teams["pursuer"].params))
    assert all(second.values()), second


def test_a_length_unit_is_what_the_learner_stores_and_its_policy_reads():
    """`network.length_unit`: the observations a rollout stores (which the statistics and the
    updates see) have the neighbour lengths in that unit, every other feature as the env gave
    it; the trainer's policy carries the same factor (4-1-2: radius 2.5 m, unit 1.25 m)."""
    trainer = Trainer(tiny(**{"evader.policy": "scripted", "pursuer.network.length_unit": 1.25}))
    state = trainer.init()
    _, data = jax.jit(trainer._rollout)(state, jax.random.key(1))
    env_obs, stored = state.env_state.obs["pursuer"], jax.tree.map(lambda x: x[0], data["pursuer"])
    stored = stored["obs"]
    lengths = {"teammates": [1], "opponents": [1], "obstacles": [0, 3]}
    for key in ("own", "teammates", "opponents", "obstacles"):
        want = np.array(env_obs[key])
        want[..., lengths.get(key, [])] *= 2.0
        np.testing.assert_allclose(stored[key], want, rtol=1e-6, err_msg=key)
    policy = trainer.policies(state)["pursuer"]
    assert float(policy.variables["length_scale"]) == 2.0


SEEDS = (0, 1, 2)
"""The learning tests train these three seeds, the first three, and judge their mean: at these
small budgets single seeds vary widely (one in six fails to learn), so no one seed is a fair
sample, and the mean of three holds with a margin on every triple measured."""


def _train_seeds(trainer: Trainer, key: jax.Array) -> list[dict[str, jax.Array]]:
    """`trainer.evaluate` (on `key`'s arenas) after training each of `SEEDS` with `trainer`'s
    config; one compiled iteration serves every seed."""
    step = jax.jit(trainer.iteration, donate_argnums=0)
    evaluate = jax.jit(trainer.evaluate)
    out = []
    for seed in SEEDS:
        state = trainer.init(seed)
        for _ in range(trainer.config.num_iterations):
            state, metrics = step(state)
        assert all(np.isfinite(float(v)) for k, v in metrics.items() if k.startswith("reward/"))
        out.append(evaluate(state, key))
    return out


def test_pursuers_learn_to_capture_the_scripted_evader():
    """Pursuers trained briefly capture clearly more often than untrained ones, on the mean of
    three seeds.

    4-1-2 arena, kinematic backend, against the scripted (fleeing) evader, 128 evaluation
    episodes each with fixed arenas, 160 iterations of 64 arenas x 32 steps. Measured when
    written (2026-12-05): untrained 0.016-0.023; after 80 / 120 / 160 iterations seeds 0-5
    reach 0.77 / 0.90 / 0.99, 0.84 / 0.81 / 0.95, 0.06 / 0.23 / 0.62, 0.66 / 0.45 / 0.84,
    0.23 / 0.29 / 0.39 and 0.33 / 0.48 / 0.95. The mean of seeds 0-2 is 0.85 (seeds 3-5:
    0.73) against a bound of untrained + 0.4; 128 Bernoulli episodes give each seed a standard
    error under 0.045. (With 32 arenas a seed, half the batch, two seeds in six had not begun to
    learn after 160 iterations.)
    """
    config = default_config("4-1-2").override(
        {
            "backend": "kinematic",
            "evader.policy": "scripted",
            "ppo.num_envs": 64,
            "ppo.unroll_length": 32,
            "env_steps": 64 * 32 * 160,
            "ppo.learning_rate": 1e-3,
            "eval_envs": 128,
            "eval_every": 0,
        }
    )
    trainer = Trainer(config)
    key = jax.random.key(123)
    untrained = [jax.jit(trainer.evaluate)(trainer.init(seed), key) for seed in SEEDS]
    trained = _train_seeds(trainer, key)

    def mean(results: list[dict[str, jax.Array]], name: str) -> float:
        return float(np.mean([float(m[f"eval/pursuer_vs_scripted/{name}"]) for m in results]))

    before, after = mean(untrained, "success_rate"), mean(trained, "success_rate")
    print(f"success vs scripted evader, mean of seeds {SEEDS}: {before:.3f} -> {after:.3f}")
    assert after >= before + 0.4
    # Capturing pays: the pursuers' episodic return (mean per agent) rises with success.
    assert mean(trained, "pursuer_return") > mean(untrained, "pursuer_return")


def test_evaders_learn_to_outlast_random_evaders():
    """Evaders trained briefly against the scripted pursuers survive far longer than random ones,
    on the mean of three seeds.

    The default training setup of the evaders (step size 3e-3, the flee shaping of
    `training_env`), 4 scripted pursuers and 1 evader with 2 obstacles in a 4 m arena (4-1-2's
    counts, room to run), kinematic backend, 100 iterations of 32 arenas x 32 steps, 128
    evaluation episodes with fixed arenas. Measured when written (2026-12-05): random evaders
    are caught after 55.5 steps on average, untrained networks after 55.1-55.7; after 100
    iterations seeds 0-5 last 223 / 207 / 185 / 172 / 396 / 67 steps (seed 5 had not taken off
    yet: 49 / 60 / 67 at 60 / 80 / 100). The mean of seeds 0-2 is 205 steps (seeds 3-5: 212)
    against a bound of twice the random evaders'. Before the diagnosis of issue 10 (step size
    3e-4, no flee shaping) the evaders did not improve at all.
    """
    config = default_config("4-1-2").override(
        {
            "backend": "kinematic",
            "pursuer.policy": "scripted",
            "env.arena.radius": 4.0,
            "ppo.num_envs": 32,
            "ppo.unroll_length": 32,
            "env_steps": 32 * 32 * 100,
            "eval_envs": 128,
            "eval_every": 0,
        }
    )
    trainer = Trainer(config)
    key = jax.random.key(123)
    keys = jax.random.split(key, config.eval_envs)
    random_pair = {
        "pursuer": trainer.scripted["pursuer"],
        "evader": make_policy("random", config.env, "evader"),
    }
    random_length = float(
        np.mean(play_episodes(trainer.eval_env, random_pair, keys).metrics["episode/length"])
    )
    lengths = [float(m["eval/evader_vs_scripted/length"]) for m in _train_seeds(trainer, key)]
    print(f"time to capture: random evaders {random_length:.1f}, trained {lengths} steps")
    assert np.mean(lengths) >= 2 * random_length


def test_two_devices_match_one_device(tmp_path):
    """Data-parallel over 2 (forced) CPU devices gives the 1-device parameters."""
    script = textwrap.dedent(
        """
        import json, sys
        import jax, jax.numpy as jnp, numpy as np
        from pe_mjx.experiment import ExperimentConfig
        from pe_mjx.ppo.train import Trainer
        assert len(jax.devices()) == 2, jax.devices()
        cfg = ExperimentConfig.from_dict(json.loads(sys.argv[1]))
        out = {}
        for n in (1, 2):
            mesh = jax.sharding.Mesh(np.array(jax.devices()[:n]), ("data",))
            trainer = Trainer(cfg, mesh=mesh)
            state = trainer.init()
            step = jax.jit(trainer.iteration)
            for _ in range(2):
                state, _ = step(state)
            shards = state.env_state.world.pos.sharding.device_set
            out[n] = (jax.tree.map(np.asarray, state.teams["pursuer"].params), len(shards))
        diffs = jax.tree.leaves(jax.tree.map(lambda a, b: float(np.max(np.abs(a - b))),
                                             out[1][0], out[2][0]))
        print(json.dumps({"max_diff": max(diffs), "devices": [out[1][1], out[2][1]]}))
        """
    )
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    cfg = tiny(env_steps=8 * 8 * 2).to_dict()
    result = subprocess.run(
        [sys.executable, "-c", script, json.dumps(cfg)],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["devices"] == [1, 2]
    assert report["max_diff"] < 1e-4, report
