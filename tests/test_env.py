"""The env (SPEC 2.2-2.6): contract of every preset and backend, each rule on a hand-placed case,
action masks, observations, rewards, MJX against the kinematic reference, placement, auto-reset.

Hand-placed cases use the 2-1-1 preset (arena radius 2 m; pursuer radius 0.1 m and 0.04 m per
full-speed step; evader radius 0.15 m and 0.08 m per full-speed step; capture radius 0.25 m).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pe_mjx import env as pe_env
from pe_mjx.config import PRESETS, get_preset
from pe_mjx.env import AutoResetWrapper
from pe_mjx.names import (
    AGENT_FEATURES,
    CAPTURE,
    OBSERVATION_KEYS,
    OBSTACLE,
    OBSTACLE_FEATURES,
    OPPONENT,
    OWN_FEATURES,
    TEAMMATE,
    WALL,
)
from pe_mjx.stages.dynamics import action_table
from tests.conftest import (
    E_FULL,
    E_STOP,
    P_FULL,
    P_STOP,
    SMALL,
    fc,
    first,
    sample_actions,
    variant_config,
)

BACKENDS = ("kinematic", "mjx")
TEAMS = ("pursuer", "evader")
PURSUER_TERMS = {"wall", "obstacle", "teammate", "pursuit", "capture", "opponent"}
EVADER_TERMS = {"wall", "obstacle", "teammate", "opponent", "alive", "flee"}
OBS_KEYS = set(OBSERVATION_KEYS)


def np_obs(state, team):
    return {k: np.asarray(v) for k, v in state.obs[team].items()}


# ------------------------------------------------------------------------------------ contract


def check_contract(env: pe_env.PursuitEvasionEnv, state: pe_env.State, batch: tuple[int, ...]):
    """Shapes, dtypes and finiteness (checked in numpy: no eager JAX op compiles)."""
    cfg = env.config
    k = cfg.arena.num_obstacles
    count = {"pursuer": cfg.pursuer.num_agents, "evader": cfg.evader.num_agents}
    obs_all, reward, done, metrics, world, info = jax.device_get(
        (
            state.obs,
            state.reward,
            state.done,
            state.metrics,
            state.world,
            {k: state.info[k] for k in ("truncation", "terminated", "valid", "placement_ok")},
        )
    )
    assert set(obs_all) == set(TEAMS)
    for team in TEAMS:
        a, o = count[team], count["evader" if team == "pursuer" else "pursuer"]
        obs = obs_all[team]
        assert set(obs) == OBS_KEYS
        shapes = {
            "own": (a, OWN_FEATURES),
            "teammates": (a, a - 1, AGENT_FEATURES),
            "opponents": (a, o, AGENT_FEATURES),
            "obstacles": (a, k, OBSTACLE_FEATURES),
            "teammate_mask": (a, a - 1),
            "opponent_mask": (a, o),
            "obstacle_mask": (a, k),
            "action_mask": (a, cfg.team(team).num_actions),
        }
        for key, shape in shapes.items():
            assert obs[key].shape == (*batch, *shape), (team, key)
            want = np.bool_ if key.endswith("mask") else np.float32
            assert obs[key].dtype == want, (team, key, obs[key].dtype)
            if not key.endswith("mask"):
                assert np.isfinite(obs[key]).all(), (team, key)
        assert obs["action_mask"].any(-1).all(), "an agent has no valid action"
        assert reward[team].shape == (*batch, a) and reward[team].dtype == np.float32
        assert np.isfinite(reward[team]).all()
        assert info["valid"][team].shape == (*batch, a)
    assert done.shape == batch and done.dtype == np.float32
    assert info["truncation"].shape == batch and info["terminated"].shape == batch
    reward_keys = {m for m in metrics if m.startswith("reward/")}
    assert reward_keys == {f"reward/pursuer/{t}" for t in PURSUER_TERMS} | {
        f"reward/evader/{t}" for t in EVADER_TERMS
    }
    for name in ("captures", "success_rate", "pursuit_cost", "length", "pursuer_wall"):
        assert f"episode/{name}" in metrics
    for name, value in metrics.items():
        assert value.shape == batch and value.dtype == np.float32, name
        assert np.isfinite(value).all(), name
    n = cfg.num_agents
    assert world.pos.shape == (*batch, n, 2) and world.yaw.shape == (*batch, n)
    assert world.active.dtype == np.bool_ and world.cause.dtype == np.int32
    assert world.obstacles.shape == (*batch, k, 3)
    assert np.isfinite(world.pos).all() and np.isfinite(world.vel).all()
    return info


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("preset", list(PRESETS))
def test_contract_jit_vmap(get_compiled, preset, backend):
    """Every preset and backend: jitted, vmapped (batch 2) reset and step keep SPEC 2.5's layout.

    240-60-120 with MJX: tracing and compiling its vmapped step took 31 s on an idle 2-core CPU
    (61 s with the machine's load average at 8), under the ~60 s budget, so it runs the same test
    as the others; a single unbatched step is barely cheaper (tracing dominates).
    """
    c = get_compiled(preset, backend)
    state = c.batch_reset(jax.random.split(jax.random.key(0), 2))
    info = check_contract(c.env, state, (2,))
    assert info["placement_ok"].all()
    assert np.all(np.asarray(state.done) == 0)
    rng = np.random.default_rng(1)
    for _ in range(2):
        state = c.batch_step(state, sample_actions(rng, state.obs))
        check_contract(c.env, state, (2,))
    assert np.all(np.asarray(state.world.step) == 2)
    # the two arenas of the batch are different draws
    pos = np.asarray(state.world.pos)
    assert not np.allclose(pos[0], pos[1])


def test_bad_backend_and_reset_to_shapes(get_compiled):
    with pytest.raises(ValueError, match="backend"):
        pe_env.make(SMALL, backend="brax")
    with pytest.raises(TypeError, match="a preset name or an EnvConfig, got NoneType"):
        pe_env.make(None)  # was AttributeError: 'NoneType' object has no attribute 'pursuer'
    with pytest.raises(ValueError, match=r"unknown preset \['2-1-1'\]"):
        get_preset(["2-1-1"])  # was TypeError: unhashable type: 'list'
    c = get_compiled(SMALL, "kinematic")
    with pytest.raises(ValueError, match="reset_to"):
        c.reset_to(jnp.zeros((3, 3)), jnp.zeros((1, 3)), jnp.zeros((1, 3)))


# ------------------------------------------------------------------------ rules (SPEC 2.3)

FAR_OBSTACLE = [[0.0, -1.4, 0.3]]


@pytest.fixture(params=BACKENDS)
def small(request, get_compiled):
    return get_compiled(SMALL, request.param)


def test_wall_hit(small):
    s = small.place([[1.87, 0, 0], [-1.0, 1.0, 0]], [[-0.8, -0.2, 0]], FAR_OBSTACLE)
    s = small.step(s, small.actions([P_FULL, P_STOP], E_STOP))
    assert np.asarray(s.world.cause).tolist() == [WALL, 0, 0]
    assert np.asarray(s.world.active).tolist() == [False, True, True]
    assert float(s.done) == 0
    assert float(s.metrics["episode/pursuer_wall"]) == 1
    assert float(s.metrics["reward/pursuer/wall"]) == pytest.approx(-10.0)  # f_c(gap <= 0) = r_c
    assert np.asarray(s.world.vel[0]).tolist() == [0, 0]


def test_obstacle_hit(small):
    # pursuer 1 is 0.02 m from the obstacle and drives 0.04 m into it
    s = small.place([[-1.0, 1.0, 0], [0.0, -0.98, -math.pi / 2]], [[0.8, 0.5, 0]], FAR_OBSTACLE)
    s = small.step(s, small.actions([P_STOP, P_FULL], E_STOP))
    assert np.asarray(s.world.cause).tolist() == [0, OBSTACLE, 0]
    assert float(s.metrics["episode/pursuer_obstacle"]) == 1
    assert float(s.metrics["reward/pursuer/obstacle"]) == pytest.approx(-10.0)
    assert float(s.done) == 0


def test_capture_by_every_pursuer_within_eps_ends_episode(small):
    # evader at rest; pursuer 0 drives from 0.28 m to 0.24 m; pursuer 1 already at 0.24 m
    s = small.place([[0.02, 0.4, 0], [0.54, 0.4, math.pi]], [[0.3, 0.4, 0]], FAR_OBSTACLE)
    s = small.step(s, small.actions([P_FULL, P_STOP], E_STOP))
    assert np.asarray(s.world.cause).tolist() == [CAPTURE] * 3
    assert not np.asarray(s.world.active).any()
    assert np.asarray(s.world.captures).tolist() == [1, 1, 1]
    assert float(s.metrics["episode/captures"]) == 1
    assert float(s.metrics["episode/success_rate"]) == 1
    # r_s to each capturing pursuer, nothing else (the teammates are 0.28 m apart: gap > d_danger)
    r_s = small.env.config.reward.capture
    np.testing.assert_allclose(s.reward["pursuer"], [r_s, r_s], atol=1e-5)
    assert float(s.metrics["reward/pursuer/capture"]) == pytest.approx(2 * r_s)
    assert float(s.metrics["reward/pursuer/pursuit"]) == 0
    # the evader is in contact with both: f_c = r_c twice, and no alive bonus
    np.testing.assert_allclose(s.reward["evader"], [-20.0], atol=1e-5)
    assert float(s.metrics["reward/evader/alive"]) == 0
    # all evaders incapacitated: termination, not truncation
    assert float(s.done) == 1
    assert bool(s.info["terminated"]) and float(s.info["truncation"]) == 0


def test_pursuer_pursuer_collision_ends_episode(small):
    s = small.place([[-0.5, 1.0, 0], [-0.29, 1.0, math.pi]], [[0.8, -0.3, 0]], FAR_OBSTACLE)
    s = small.step(s, small.actions(P_FULL, E_STOP))
    assert np.asarray(s.world.cause).tolist() == [TEAMMATE, TEAMMATE, 0]
    assert float(s.metrics["episode/pursuer_teammate"]) == 2
    assert float(s.metrics["reward/pursuer/teammate"]) == pytest.approx(-20.0)
    # all pursuers incapacitated: termination
    assert float(s.done) == 1 and bool(s.info["terminated"])
    assert float(s.info["truncation"]) == 0
    assert float(s.metrics["episode/pursuit_cost"]) == 2


def test_touching_incapacitated_agents(small):
    """Pursuer 0 starts inside the obstacle (step 1: OBSTACLE); in step 2 pursuer 1 (TEAMMATE)
    and the evader (OPPONENT, not a capture: pursuer 0 is no longer active) drive into it."""
    obstacle = [[0.0, 0.0, 0.3]]
    s = small.place([[0.39, 0, 0], [0.39, 0.22, -math.pi / 2]], [[0.66, 0, math.pi]], obstacle)
    s = small.step(s, small.actions(P_STOP, E_STOP))
    assert np.asarray(s.world.cause).tolist() == [OBSTACLE, 0, 0]
    assert float(s.done) == 0
    s = small.step(s, small.actions(P_FULL, E_FULL))
    assert np.asarray(s.world.cause).tolist() == [OBSTACLE, TEAMMATE, OPPONENT]
    assert np.asarray(s.world.captures).tolist() == [0, 0, 0]
    assert float(s.metrics["episode/evader_opponent"]) == 1
    assert float(s.metrics["episode/pursuer_teammate"]) == 1
    assert float(s.done) == 1


def test_incapacitated_agents_never_move(small):
    s = small.place([[1.87, 0, 0], [-1.0, 1.0, 0]], [[-0.8, -0.2, 0]], FAR_OBSTACLE)
    s = small.step(s, small.actions([P_FULL, P_STOP], E_STOP))
    assert not bool(s.world.active[0])
    frozen_pose = np.asarray(small.env.poses(s)["pursuer"][0])
    frozen_q = None if s.physics is None else np.asarray(s.physics.qpos[:3])
    rng = np.random.default_rng(0)
    for t in range(40):  # any actions, masked or not
        s = small.step(s, small.actions(rng.integers(0, 39, 2), rng.integers(0, 95, 1)))
        np.testing.assert_array_equal(small.env.poses(s)["pursuer"][0], frozen_pose)
        if frozen_q is not None:
            np.testing.assert_array_equal(s.physics.qpos[:3], frozen_q)
        assert int(s.world.cause[0]) == WALL
        assert float(s.reward["pursuer"][0]) == 0
        assert not bool(s.info["valid"]["pursuer"][0])
        assert np.asarray(s.world.vel[0]).tolist() == [0, 0]
        # others keep observing it, flagged g = 1
        assert float(s.obs["pursuer"]["own"][0, 0]) == 1
        assert float(s.obs["pursuer"]["teammates"][1, 0, 0]) == 1
        assert float(s.obs["evader"]["opponents"][0, 0, 0]) == 1
        if t == 0:
            assert bool(s.info["valid"]["pursuer"][1])
    assert int(s.world.step) == 41


def test_truncation_at_1000_steps(get_compiled):
    c = get_compiled(SMALL, "kinematic")
    assert c.config.max_steps == 1000
    stop = c.actions(P_STOP, E_STOP)

    @jax.jit
    def rollout(state):
        def body(s, _):
            s = c.env.step(s, stop)
            return s, (s.done, s.info["truncation"], s.info["terminated"])

        return jax.lax.scan(body, state, None, length=1000)

    final, (done, trunc, term) = rollout(c.reset(5))
    done, trunc = np.asarray(done), np.asarray(trunc)
    assert done[:-1].sum() == 0 and trunc[:-1].sum() == 0
    assert done[-1] == 1 and trunc[-1] == 1
    assert not np.asarray(term).any()
    assert int(final.world.step) == 1000
    assert float(final.metrics["episode/length"]) == 1000


# ---------------------------------------------------------------------- masks (SPEC 2.4)


def random_scene(rng: np.random.Generator, cfg, touching: bool = False):
    """Obstacles anywhere; agents (away from the wall and obstacles unless `touching`), about half
    of them placed within 0.1 m of an obstacle or the wall so that masks have work to do."""
    R, k = cfg.arena.radius, cfg.arena.num_obstacles
    obs_r = rng.uniform(cfg.arena.obstacle_radius_min, cfg.arena.obstacle_radius_max, k)
    rho = (R - obs_r) * np.sqrt(rng.uniform(size=k))
    phi = rng.uniform(0, 2 * np.pi, k)
    obstacles = np.stack([rho * np.cos(phi), rho * np.sin(phi), obs_r], axis=1)
    poses = []
    for team in TEAMS:
        r = cfg.team(team).radius
        for _ in range(cfg.team(team).num_agents):
            while True:
                margin = rng.uniform(-0.02 if touching else 1e-3, 0.1)
                mode = rng.integers(3)
                a = rng.uniform(0, 2 * np.pi)
                if mode == 0:  # near the wall
                    p = (R - r - margin) * np.array([np.cos(a), np.sin(a)])
                elif mode == 1:  # near an obstacle
                    o = obstacles[rng.integers(k)]
                    p = o[:2] + (o[2] + r + margin) * np.array([np.cos(a), np.sin(a)])
                else:
                    p = (R - r) * np.sqrt(rng.uniform()) * np.array([np.cos(a), np.sin(a)])
                if np.linalg.norm(p) + r >= R and not touching:
                    continue
                gaps = np.linalg.norm(obstacles[:, :2] - p, axis=1) - obstacles[:, 2] - r
                if touching or gaps.min() > 1e-3:
                    break
            poses.append([p[0], p[1], rng.uniform(-np.pi, np.pi)])
    poses = np.asarray(poses, np.float32)
    p = cfg.pursuer.num_agents
    return poses[:p], poses[p:], obstacles.astype(np.float32)


def mask_checker(env):
    """jit(vmap over scenes): masks, and every agent's cause after each action index a (pursuers
    take a % 39, evaders a % 95, all at once: wall and obstacle events are per agent)."""
    n_p, n_e = env.num_actions("pursuer"), env.num_actions("evader")
    n = max(n_p, n_e)

    def check(pursuer, evader, obstacles):
        s = env.reset_to(pursuer, evader, obstacles)

        def one(a):
            actions = {
                "pursuer": jnp.full(env.num_pursuers, a % n_p, jnp.int32),
                "evader": jnp.full(env.num_evaders, a % n_e, jnp.int32),
            }
            return env.step(s, actions).world.cause

        causes = jax.vmap(one)(jnp.arange(n))  # [n, N]
        return s.obs["pursuer"]["action_mask"], s.obs["evader"]["action_mask"], causes

    return jax.jit(jax.vmap(check))


def test_masks_never_allow_wall_or_obstacle_hit(get_compiled):
    """Each unmasked action, simulated with the kinematic integrator over the look-ahead
    (mask_horizon = one control step), hits neither the wall nor an obstacle; 4 x 128 scenes
    of 4-1-2, with about half the agents within 0.1 m of the wall or an obstacle."""
    c = get_compiled("4-1-2", "kinematic")
    assert c.config.mask_horizon == pytest.approx(c.config.control_dt)
    check = mask_checker(c.env)
    n_p, n_e = c.env.num_actions("pursuer"), c.env.num_actions("evader")
    n = max(n_p, n_e)
    masked_somewhere = 0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        scenes = [random_scene(rng, c.config) for _ in range(128)]
        p, e, o = (np.stack(x) for x in zip(*scenes, strict=True))
        mask_p, mask_e, causes = (np.asarray(x) for x in check(p, e, o))
        hit = np.isin(causes, [WALL, OBSTACLE])  # [B, n, N]
        idx_p, idx_e = np.arange(n) % n_p, np.arange(n) % n_e
        allowed_p = mask_p[:, :, idx_p].transpose(0, 2, 1)  # [B, n, P]
        allowed_e = mask_e[:, :, idx_e].transpose(0, 2, 1)
        allowed = np.concatenate([allowed_p, allowed_e], axis=2)
        assert not np.any(allowed & hit), "an unmasked action hits the wall or an obstacle"
        assert mask_p.any(-1).all() and mask_e.any(-1).all()
        masked_somewhere += (~mask_p).any(-1).sum() + (~mask_e).any(-1).sum()
        # stop actions are always valid for an agent that is not touching
        v_p = action_table(c.config.pursuer)[0]
        assert mask_p[:, :, v_p == 0].all()
    assert masked_somewhere > 100  # the scenes do exercise the mask


def test_masks_leave_stop_actions_when_touching(get_compiled):
    c = get_compiled(SMALL, "kinematic")
    # pursuer 0 overlaps the obstacle, pursuer 1 overlaps the wall, the evader is free
    s = c.place([[0.35, 0, 0], [1.95, 0.0, 0]], [[-1.0, 0.5, 0]], [[0.0, 0.0, 0.3]])
    v_p = action_table(c.config.pursuer)[0]
    mask = np.asarray(s.obs["pursuer"]["action_mask"])
    np.testing.assert_array_equal(mask[0], v_p == 0)
    np.testing.assert_array_equal(mask[1], v_p == 0)
    assert np.asarray(s.obs["evader"]["action_mask"]).all()
    # also over random scenes where agents may touch: never everything masked
    rng = np.random.default_rng(11)
    for _ in range(20):
        p, e, o = random_scene(rng, c.config, touching=True)
        s = c.place(p, e, o)
        for team in TEAMS:
            assert np.asarray(s.obs[team]["action_mask"]).any(-1).all()


def test_min_turning_radius_mask(get_compiled):
    cfg = variant_config()
    assert (cfg.pursuer.min_turning_radius, cfg.evader.min_turning_radius) == (0.3, 0.5)
    c = get_compiled(cfg, "kinematic")
    # agents in open space: only the turning-radius rule masks
    s = c.place([[0.0, 0.5, 0.3], [-0.5, 0.0, 1.0]], [[0.5, 0.0, -2.0]], [[0.0, -1.2, 0.3]])
    for team, r_min in (("pursuer", 0.3), ("evader", 0.5)):
        t = cfg.team(team)
        speeds = np.linspace(0, t.max_speed, t.num_speeds)
        rates = np.linspace(-t.max_turn_rate, t.max_turn_rate, t.num_turn_rates)
        v, w = np.repeat(speeds, t.num_turn_rates), np.tile(rates, t.num_speeds)
        straight = np.abs(w) < 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            radius = np.where(straight, np.inf, v / np.abs(w))
        want = np.where(v > 0, radius >= r_min, straight)  # v = 0: only "stand still"
        mask = np.asarray(s.obs[team]["action_mask"])
        for row in mask:
            np.testing.assert_array_equal(row, want)
        assert 0 < want.sum() < want.size
    # touching an obstacle: the one stop action with omega = 0 remains
    s = c.place([[0.0, -0.85, 0.3], [-0.5, 0.0, 1.0]], [[0.5, 0.0, -2.0]], [[0.0, -1.2, 0.3]])
    mask = np.asarray(s.obs["pursuer"]["action_mask"][0])
    assert mask.sum() == 1 and mask[P_STOP]


# -------------------------------------------------------------- observations (SPEC 2.5)


def heading(vec, yaw):
    """World vector -> heading frame of an agent with this yaw."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * vec[0] + s * vec[1], -s * vec[0] + c * vec[1]])


def polar(vec, yaw):
    h = heading(vec, yaw)
    d = np.linalg.norm(h)
    return d, h[0] / d, h[1] / d


def test_observations_by_hand(get_compiled):
    c = get_compiled(SMALL, "kinematic")
    R = 2.0
    p0, p1, e0 = np.array([0.5, 0.2]), np.array([-0.6, 0.4]), np.array([0.3, -0.9])
    yaw_p0, yaw_p1, yaw_e = math.pi / 6, 2.0, -1.0
    obstacle = np.array([-0.8, -0.7, 0.35])
    s = c.place([[*p0, yaw_p0], [*p1, yaw_p1]], [[*e0, yaw_e]], [obstacle])
    # one step: pursuer 0 full speed straight, pursuer 1 stops, the evader full speed straight
    s = c.step(s, c.actions([P_FULL, P_STOP], E_FULL))
    u_p0 = np.array([math.cos(yaw_p0), math.sin(yaw_p0)])
    u_e = np.array([math.cos(yaw_e), math.sin(yaw_e)])
    p0, e0 = p0 + 0.2 * 0.2 * u_p0, e0 + 0.4 * 0.2 * u_e
    vel_p0, vel_p1, vel_e = 0.2 * u_p0, np.zeros(2), 0.4 * u_e
    assert np.asarray(s.world.active).all()
    np.testing.assert_allclose(s.world.pos, [p0, p1, e0], atol=1e-6)

    obs = np_obs(s, "pursuer")
    # own: [g, r_o, cos, sin of the world origin's bearing, v / v_max]
    d, cb, sb = polar(-p0, yaw_p0)
    np.testing.assert_allclose(obs["own"][0], [0, d / R, cb, sb, 1.0], atol=1e-5)
    # teammate pursuer 1, seen by pursuer 0: [g, d, cos, sin, vx, vy] (v over v_max = 0.2)
    d, cb, sb = polar(p1 - p0, yaw_p0)
    np.testing.assert_allclose(obs["teammates"][0, 0], [0, d / R, cb, sb, 0, 0], atol=1e-5)
    # opponent (the evader) seen by pursuer 0: its world velocity in pursuer 0's heading frame
    d, cb, sb = polar(e0 - p0, yaw_p0)
    vx, vy = heading(vel_e, yaw_p0) / 0.2
    np.testing.assert_allclose(obs["opponents"][0, 0], [0, d / R, cb, sb, vx, vy], atol=1e-5)
    # obstacle seen by pursuer 0: [d, cos, sin, r] (centre distance; lengths over R)
    d, cb, sb = polar(obstacle[:2] - p0, yaw_p0)
    np.testing.assert_allclose(obs["obstacles"][0, 0], [d / R, cb, sb, 0.35 / R], atol=1e-5)
    # pursuer 1 (at rest) sees pursuer 0 moving
    d, cb, sb = polar(p0 - p1, yaw_p1)
    vx, vy = heading(vel_p0, yaw_p1) / 0.2
    np.testing.assert_allclose(obs["teammates"][1, 0], [0, d / R, cb, sb, vx, vy], atol=1e-5)
    assert obs["own"][1, 4] == pytest.approx(0.0)

    obs = np_obs(s, "evader")
    d, cb, sb = polar(-e0, yaw_e)
    np.testing.assert_allclose(obs["own"][0], [0, d / R, cb, sb, 1.0], atol=1e-5)
    assert obs["teammates"].shape == (1, 0, 6)
    for j, (p, vel) in enumerate(((p0, vel_p0), (p1, vel_p1))):
        d, cb, sb = polar(p - e0, yaw_e)
        vx, vy = heading(vel, yaw_e) / 0.4  # normalised by the observer's max speed
        np.testing.assert_allclose(obs["opponents"][0, j], [0, d / R, cb, sb, vx, vy], atol=1e-5)
    for key in ("teammate_mask", "opponent_mask", "obstacle_mask"):
        assert obs[key].all()


# ---------------------------------------------------------------- rewards (SPEC 2.6)


def check_terms(s, expected: dict[str, dict[str, np.ndarray]]):
    """Per-agent totals and the per-term `reward/<team>/<term>` metrics."""
    for team, terms in expected.items():
        total = sum(terms.values())
        np.testing.assert_allclose(s.reward[team], total, rtol=1e-5, atol=1e-5)
        for name, values in terms.items():
            got = float(s.metrics[f"reward/{team}/{name}"])
            assert got == pytest.approx(float(np.sum(values)), rel=1e-5, abs=1e-5), (team, name)


def test_rewards_active_evader_by_hand(get_compiled):
    """Eqs. (3) and (4) with f_p = 10 / max(d, d_cap) on a hand-placed state (d_cap = 0.4 m and
    epsilon = 0.3 m here, so that the floor is reached without a capture); all stand still."""
    cfg = variant_config()
    assert (cfg.reward.capture_distance, cfg.capture_eps) == (0.4, 0.3)
    c = get_compiled(cfg, "kinematic")
    p0, p1, e0 = np.array([1.75, 0.0]), np.array([1.75, 0.3]), np.array([1.4, 0.0])
    o = np.array([1.45, -0.5, 0.3])
    s = c.place([[*p0, 0], [*p1, 0]], [[*e0, 0]], [o])
    s = c.step(s, c.actions(P_STOP, E_STOP))
    assert np.asarray(s.world.active).all()

    def dist(a, b):
        return float(np.linalg.norm(a - b))

    d_p0e, d_p1e = dist(p0, e0), dist(p1, e0)
    # by-hand spot values
    assert fc(2 - 1.75 - 0.1) == pytest.approx(-10 * 0.05 / 0.35)
    assert 10 / max(d_p0e, 0.4) == pytest.approx(25.0)  # d = 0.35 < d_cap
    expected = {
        "pursuer": {
            "wall": np.array([fc(2 - 1.75 - 0.1), fc(2 - np.linalg.norm(p1) - 0.1)]),
            "obstacle": np.array([fc(dist(p0, o[:2]) - 0.4), fc(dist(p1, o[:2]) - 0.4)]),
            "teammate": np.array([fc(0.3 - 0.2), fc(0.3 - 0.2)]),
            "pursuit": np.array([10 / max(d_p0e, 0.4), 10 / max(d_p1e, 0.4)]),
            "capture": np.zeros(2),
            "opponent": np.zeros(2),
        },
        "evader": {
            "wall": np.array([fc(2 - 1.4 - 0.15)]),
            "obstacle": np.array([fc(dist(e0, o[:2]) - 0.45)]),
            "teammate": np.zeros(1),
            "opponent": np.array([fc(d_p0e - 0.25) + fc(d_p1e - 0.25)]),
            "alive": np.ones(1),
        },
    }
    # the hand-placed state exercises every non-capture term
    pursuer, evader = expected["pursuer"], expected["evader"]
    for values in (pursuer["wall"], pursuer["teammate"], pursuer["pursuit"]):
        assert np.all(values != 0)
    assert pursuer["obstacle"][0] != 0 and evader["obstacle"][0] != 0
    assert evader["opponent"][0] != 0
    check_terms(s, expected)


def test_rewards_capture_step_by_hand(get_compiled):
    """The capture step with epsilon = 0.3 m (no contact needed): pursuer 0 within epsilon gets
    r_s; pursuer 1 just outside gets f_c(gap) for the now incapacitated evader."""
    cfg = variant_config()
    assert cfg.capture_eps == 0.3
    c = get_compiled(cfg, "kinematic")
    s = c.place([[0.28, 0.5, math.pi], [-0.33, 0.5, 0]], [[0.0, 0.5, 0]], FAR_OBSTACLE)
    s = c.step(s, c.actions(P_STOP, E_STOP))
    assert np.asarray(s.world.cause).tolist() == [CAPTURE, 0, CAPTURE]
    assert np.asarray(s.world.captures).tolist() == [1, 0, 1]
    assert float(s.done) == 1
    expected = {
        "pursuer": {
            "wall": np.zeros(2),
            "obstacle": np.zeros(2),
            "teammate": np.array([fc(0.61 - 0.2)] * 2),
            "pursuit": np.zeros(2),
            "capture": np.array([c.env.config.reward.capture, 0.0]),
            "opponent": np.array([0.0, fc(0.33 - 0.25)]),
        },
        "evader": {
            "wall": np.zeros(1),
            "obstacle": np.zeros(1),
            "teammate": np.zeros(1),
            "opponent": np.array([fc(0.28 - 0.25) + fc(0.33 - 0.25)]),
            "alive": np.zeros(1),
        },
    }
    assert expected["pursuer"]["opponent"][1] == pytest.approx(-10 * 0.12 / 0.28)
    check_terms(s, expected)
    # capture within epsilon but not beyond it
    s = c.place([[0.31, 0.5, math.pi], [-0.33, 0.5, 0]], [[0.0, 0.5, 0]], FAR_OBSTACLE)
    s = c.step(s, c.actions(P_STOP, E_STOP))
    assert np.asarray(s.world.active).all() and float(s.done) == 0


def test_no_reward_after_incapacitation(small):
    s = small.place([[-0.5, 1.0, 0], [-0.29, 1.0, math.pi]], [[0.8, -0.3, 0]], FAR_OBSTACLE)
    s = small.step(s, small.actions(P_FULL, E_STOP))
    assert float(s.metrics["reward/pursuer/teammate"]) == pytest.approx(-20.0)
    assert np.asarray(s.info["valid"]["pursuer"]).all()
    s = small.step(s, small.actions(P_FULL, E_FULL))
    assert not np.asarray(s.info["valid"]["pursuer"]).any()
    np.testing.assert_array_equal(s.reward["pursuer"], [0.0, 0.0])
    assert float(s.metrics["reward/pursuer/teammate"]) == 0


# ---------------------------------------------------------- MJX vs kinematic, determinism


@pytest.mark.parametrize("physics_dt", [0.2, 0.05])
def test_mjx_matches_kinematic_reference(get_compiled, physics_dt):
    """MJX trajectories follow the exact arcs of the kinematic backend: over 50 steps of the same
    random (mask-valid) actions, each agent's position and yaw stay within MJX_POSE_TOL (float32
    rounding; tests/test_rules.py checks events and poses at the paper presets), at the default
    single physics step per control step and with 4 substeps."""
    config = get_preset(SMALL).replace(physics_dt=physics_dt)
    kin, mjx = get_compiled(config, "kinematic"), get_compiled(config, "mjx")
    compared = total = 0
    for seed in range(4):
        sk, sm = kin.reset(seed), mjx.reset(seed)
        np.testing.assert_array_equal(sk.world.pos, sm.world.pos)
        both = np.ones(kin.env.num_agents, bool)
        rng = np.random.default_rng(100 + seed)
        for _ in range(50):
            actions = sample_actions(rng, sk.obs)
            sk, sm = kin.step(sk, actions), mjx.step(sm, actions)
            both &= np.asarray(sk.world.active) & np.asarray(sm.world.active)
            dpos = np.abs(np.asarray(sm.world.pos) - np.asarray(sk.world.pos)).max(-1)
            dyaw = np.asarray(sm.world.yaw, np.float64) - np.asarray(sk.world.yaw)
            dyaw = np.abs((dyaw + np.pi) % (2 * np.pi) - np.pi)
            assert np.all(dpos[both] <= pe_env.MJX_POSE_TOL), dpos
            assert np.all(dyaw[both] <= pe_env.MJX_POSE_TOL), dyaw
            compared += both.sum()
            total += both.size
    assert compared >= 0.5 * total


@pytest.mark.parametrize("backend", BACKENDS)
def test_same_seed_same_trajectory(get_compiled, backend):
    c = get_compiled("4-1-2", backend)

    def run():
        state = c.batch_reset(jnp.stack([jax.random.key(7), jax.random.key(7)]))
        rng = np.random.default_rng(8)
        states = []
        for _ in range(10):
            one = sample_actions(rng, first(state.obs))
            actions = {t: jnp.asarray(np.stack([a, a])) for t, a in one.items()}
            state = c.batch_step(state, actions)
            states.append(state.world)
        return states

    a, b = run(), run()
    for wa, wb in zip(a, b, strict=True):
        for xa, xb in zip(jax.tree.leaves(wa), jax.tree.leaves(wb), strict=True):
            np.testing.assert_array_equal(xa, xb)
            np.testing.assert_array_equal(xa[0], xa[1])  # same key in the batch, same result
    other = c.batch_reset(jnp.stack([jax.random.key(9), jax.random.key(7)]))
    assert not np.allclose(other.world.obstacles[0], other.world.obstacles[1])


# ----------------------------------------------------------------------- placement


@pytest.mark.parametrize("preset", list(PRESETS))
def test_placement_never_overlaps(get_compiled, preset):
    """Property: for any seed, spawn gaps between every pair of obstacles/agents and to the wall
    are at least spawn_clearance, and info["placement_ok"] is set."""
    c = get_compiled(preset, "kinematic")
    cfg = c.config
    clear = cfg.arena.spawn_clearance
    radii = np.concatenate(
        [
            np.full(cfg.pursuer.num_agents, cfg.pursuer.radius),
            np.full(cfg.evader.num_agents, cfg.evader.radius),
        ]
    )

    @settings(deadline=None, max_examples=50 if cfg.num_agents < 100 else 15, database=None)
    @given(seed=st.integers(0, 2**31 - 2))
    def check(seed):
        states = c.batch_reset(jnp.stack([jax.random.key(seed), jax.random.key(seed + 1)]))
        assert np.asarray(states.info["placement_ok"]).all()
        for b in range(2):
            o = np.asarray(states.world.obstacles[b], np.float64)
            pos = np.concatenate([o[:, :2], np.asarray(states.world.pos[b], np.float64)])
            r = np.concatenate([o[:, 2], radii])
            assert np.all(o[:, 2] >= cfg.arena.obstacle_radius_min - 1e-6)
            assert np.all(o[:, 2] <= cfg.arena.obstacle_radius_max + 1e-6)
            gaps = np.linalg.norm(pos[:, None] - pos[None], axis=-1) - r[:, None] - r[None]
            np.fill_diagonal(gaps, np.inf)
            assert gaps.min() >= clear - 1e-5
            wall_gap = cfg.arena.radius - np.linalg.norm(pos, axis=1) - r
            assert wall_gap.min() >= clear - 1e-5
            yaw = np.asarray(states.world.yaw[b])
            assert np.all((yaw >= -math.pi) & (yaw <= math.pi))

    check()


# ---------------------------------------------------------------------- auto-reset


def test_auto_reset_draws_fresh_arena_and_keeps_finished_step(get_compiled):
    cfg = variant_config()
    assert cfg.max_steps == 2
    c = get_compiled(cfg, "kinematic")
    wrapped = AutoResetWrapper(c.env)
    step = jax.jit(wrapped.step)
    stop = c.actions(P_STOP, E_STOP)
    s = c.place([[1.0, 0, 0], [-1.0, 0, 0]], [[0, 1.0, 0]], FAR_OBSTACLE)
    layouts = [np.asarray(s.world.obstacles)]
    for episode in range(2):
        s = step(s, stop)
        assert float(s.done) == 0 and int(s.world.step) == 1
        before = s
        s = step(s, stop)
        # the finished step's done, truncation, reward and metrics are kept ...
        unwrapped = c.step(before, stop)
        assert float(s.done) == 1 and float(s.info["truncation"]) == 1
        for team in TEAMS:
            np.testing.assert_array_equal(s.reward[team], unwrapped.reward[team])
        assert float(s.metrics["episode/length"]) == 2
        # ... while world and observations are a fresh draw
        assert int(s.world.step) == 0
        assert np.asarray(s.world.active).all()
        layouts.append(np.asarray(s.world.obstacles))
        assert not np.allclose(layouts[-1], layouts[-2]), f"episode {episode}: same arena"
        pos, obstacles = np.asarray(s.world.pos), np.asarray(s.world.obstacles)
        own = np.concatenate([s.obs["pursuer"]["own"], s.obs["evader"]["own"]])
        np.testing.assert_allclose(own[:, 1], np.linalg.norm(pos, axis=1) / 2.0, atol=1e-6)
        np.testing.assert_allclose(own[:, 4], 0.0)
        d_obstacle = np.linalg.norm(pos - obstacles[0, :2], axis=1) / 2.0
        np.testing.assert_allclose(
            s.obs["pursuer"]["obstacles"][:, 0, 0], d_obstacle[:2], atol=1e-6
        )


def test_auto_reset_step_batch_matches_vmapped_step(get_compiled):
    """The trainer's batched auto-reset (the reset skipped when no arena is done) gives exactly
    `vmap(step)`: none done, all done, and a mixed batch."""
    c = get_compiled(variant_config(), "kinematic")
    wrapped = AutoResetWrapper(c.env)
    stop = c.actions(P_STOP, E_STOP)
    s0 = c.place([[1.0, 0, 0], [-1.0, 0, 0]], [[0, 1.0, 0]], FAR_OBSTACLE)
    s1 = c.step(s0, stop)  # one step in: done at its next step
    vmapped, batched = jax.jit(jax.vmap(wrapped.step)), jax.jit(wrapped.step_batch)
    actions = jax.tree.map(lambda a: jnp.stack([a, a]), stop)
    for pair in ((s0, s0), (s0, s1)):
        state = jax.tree.map(lambda a, b: jnp.stack([a, b]), *pair)
        for _ in range(3):
            expected, got = vmapped(state, actions), batched(state, actions)
            assert jax.tree.structure(expected) == jax.tree.structure(got)
            for e, g in zip(jax.tree.leaves(expected), jax.tree.leaves(got), strict=True):
                if jax.dtypes.issubdtype(e.dtype, jax.dtypes.prng_key):
                    e, g = jax.random.key_data(e), jax.random.key_data(g)
                np.testing.assert_array_equal(np.asarray(e), np.asarray(g))
            state = got


def test_out_of_range_actions_are_clamped_and_counted():
    """An index below 0 plays action 0, one at or above num_actions the last action (never a
    wrap-around), and `metrics["invalid_actions"]` counts them."""
    env = pe_env.make("2-1-1", backend="kinematic")
    state = env.reset(jax.random.key(0))
    assert float(state.metrics["invalid_actions"]) == 0.0
    last = {t: env.config.team(t).num_actions - 1 for t in ("pursuer", "evader")}
    bad = {"pursuer": jnp.array([-1, 999]), "evader": jnp.array([-1000])}
    good = {"pursuer": jnp.array([0, last["pursuer"]]), "evader": jnp.array([0])}
    clamped, reference = env.step(state, bad), env.step(state, good)
    np.testing.assert_array_equal(clamped.world.pos, reference.world.pos)
    np.testing.assert_array_equal(clamped.world.yaw, reference.world.yaw)
    assert float(clamped.metrics["invalid_actions"]) == 3.0
    assert float(reference.metrics["invalid_actions"]) == 0.0
