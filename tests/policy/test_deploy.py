"""The robot controller (pe_mjx.policy.deploy): velocity estimates and observations equal to the
env's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.names import TEAMS
from pe_mjx.policy.deploy import Controller, arc_speed
from pe_mjx.policy.scripted import make_policy
from pe_mjx.stages.dynamics import action_table

ROBOTS = "4-2-2"  # the paper's physical setup: Ackermann pursuers, R_min = 0.4 m
# Velocity features (own speed, others' vx, vy: normalised by the observer's max speed) from the
# arc fit of float32 poses agree with the env's within this. The other features come from the same
# poses through the same function, compiled apart from `step` (other XLA fusions): within
# FEATURE_TOL (float32 rounding); masks are equal.
VELOCITY_TOL = 1e-4
FEATURE_TOL = 1e-6
VELOCITY_COLUMNS = {"own": [4], "teammates": [4, 5], "opponents": [4, 5], "obstacles": []}


def arc_pose(pose0: np.ndarray, v: float, w: float, t: float) -> np.ndarray:
    """The pose after t seconds of constant (v, w) from pose0 (float64)."""
    x, y, yaw = pose0
    if abs(w) < 1e-12:
        return np.array([x + v * t * np.cos(yaw), y + v * t * np.sin(yaw), yaw])
    yaw1 = yaw + w * t
    return np.array(
        [x + v / w * (np.sin(yaw1) - np.sin(yaw)), y - v / w * (np.cos(yaw1) - np.cos(yaw)), yaw1]
    )


@pytest.mark.parametrize("v, w", [(0.17, 0.7), (0.3, -1.5), (0.2, 0.0), (-0.1, 0.4)])
def test_velocity_exact_on_arcs_at_irregular_times(v, w):
    """A robot on a constant (v, w) arc, its poses delivered at irregular times (and one out of
    order): every estimate is v (cos psi, sin psi) at the newest heading, whatever the window."""
    rng = np.random.default_rng(0)
    pose0 = np.array([0.3, -0.2, 2.9])
    times = np.cumsum(rng.uniform(0.01, 0.15, size=40))
    config = get_preset(ROBOTS)
    for window in (0.2, 0.5):
        ctrl = Controller(config, velocity_window=window)
        assert np.all(ctrl.velocities()["pursuer"] == 0)
        for i, t in enumerate(times):
            pose = arc_pose(pose0, v, w, t)
            ctrl.update("pursuer", 1, pose, t)
            if i == 5:
                ctrl.update("pursuer", 1, arc_pose(pose0, v, w, t - 1), t - 1)  # stale: ignored
            if i == 0:
                assert np.all(ctrl.velocities()["pursuer"][1] == 0)  # one pose: at rest
                continue
            want = v * np.array([np.cos(pose[2]), np.sin(pose[2])])
            np.testing.assert_allclose(ctrl.velocities()["pursuer"][1], want, atol=1e-12)


def test_arc_speed_ignores_sideways_motion():
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.05, 0.0]])  # slid 5 cm to the left
    assert arc_speed(np.array([0.0, 0.2]), poses) == pytest.approx(0.0, abs=1e-15)


def _rollout(config, steps: int, seed: int):
    """Scripted pursuers against random evaders in the kinematic env: states [steps + 1]. Evader 0
    starts 0.1 m from pursuer 0, so the pair is down (captured) after the first step."""
    env = PursuitEvasionEnv(config, backend="kinematic")
    policies = {
        "pursuer": make_policy("scripted", config, "pursuer"),
        "evader": make_policy("random", config, "evader"),
    }

    @jax.jit
    def step(state, rng):
        keys = jax.random.split(rng)
        actions = {t: policies[t](state.obs[t], k) for t, k in zip(TEAMS, keys, strict=True)}
        return env.step(state, actions)

    @jax.jit
    def reset(rng):
        state = env.reset(rng)
        p = env.num_pursuers
        world = state.world.replace(pos=state.world.pos.at[p].set(state.world.pos[0] + 0.1))
        return state.replace(world=world, obs=env.observe(world))

    state = reset(jax.random.key(seed))
    states = [state]
    for k in jax.random.split(jax.random.key(seed + 1), steps):
        state = step(state, k)
        states.append(state)
    return env, states, policies


def test_observations_equal_env_on_simulated_episode():
    """Poses of a simulated episode fed at the control rate: the controller's observations are
    the env's (masks with the minimum turning radius exactly, velocities within VELOCITY_TOL),
    including robots that went down, and its commands are the policy's actions on the env's
    observations."""
    config = get_preset(ROBOTS).replace(max_steps=10_000)
    env, states, policies = _rollout(config, steps=40, seed=3)
    ctrl = Controller(config, {"pursuer": policies["pursuer"]})
    pursue = jax.jit(policies["pursuer"])
    worst = 0.0
    for i, state in enumerate(jax.device_get(states)):
        if state.done > 0:
            break
        w = state.world
        pose = np.concatenate([w.pos, w.yaw[:, None]], axis=1)
        for team, sl in env.team_slices.items():
            ctrl.update_team(team, pose[sl], i * config.control_dt)
        down = {t: ~w.active[sl] for t, sl in env.team_slices.items()}
        obstacles = w.obstacles
        if i == 0:  # placed overlapping (the env downs both on the first step): refused
            with pytest.raises(ValueError, match=r"pursuer 0 at .* overlaps evader 0"):
                ctrl.observe(obstacles, down)
            continue
        obs = ctrl.observe(obstacles, down)
        for team in TEAMS:
            for key, want in state.obs[team].items():
                got, want = np.asarray(obs[team][key]), np.asarray(want)
                assert got.shape == want.shape and got.dtype == want.dtype, (team, key)
                if want.dtype == bool:
                    np.testing.assert_array_equal(got, want, err_msg=f"{team} {key} step {i}")
                    continue
                vel = VELOCITY_COLUMNS[key]
                rest = [c for c in range(want.shape[-1]) if c not in vel]
                np.testing.assert_allclose(
                    got[..., rest], want[..., rest], rtol=0, atol=FEATURE_TOL
                )
                if vel and want.size:
                    worst = max(worst, float(np.max(np.abs(got[..., vel] - want[..., vel]))))
        commands = ctrl.act(obstacles, down)["pursuer"]
        actions = np.asarray(pursue(state.obs["pursuer"], jax.random.key(0)))
        v, w = action_table(config.pursuer)
        want = np.stack([v[actions], w[actions]], axis=-1) * ~down["pursuer"][:, None]
        np.testing.assert_allclose(commands, want, atol=1e-7)
        moving = commands[:, 0] > 0
        radius = commands[moving, 0] / np.maximum(np.abs(commands[moving, 1]), 1e-9)
        assert np.all(radius >= config.pursuer.min_turning_radius - 1e-6)
    assert i > 20, "the episode ended too early to test much"
    print(f"largest velocity feature difference: {worst:.2e}")
    assert worst < VELOCITY_TOL, worst
    moved = np.abs(np.asarray(states[i - 1].world.vel)).max()
    assert moved > 0.1, "the velocities compared were all zero"
    assert not np.asarray(states[i - 1].world.active).all(), "nobody went down in the episode"
    assert np.asarray(states[i - 1].world.active).sum() >= 3, "the episode had few robots left"


def test_obstacle_count_and_down_robots():
    """Any obstacle count (K = 0 too); a robot that is down is observed with g = 1, zero
    velocity, and commanded (0, 0)."""
    config = get_preset(ROBOTS)
    ctrl = Controller(config, {t: make_policy("scripted", config, t) for t in TEAMS})
    pursuers = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, np.pi], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
    evaders = np.array([[0.0, 2.0, 0.0], [0.0, -2.0, 0.0]])
    for t in (0.0, 0.2):
        ctrl.update_team("pursuer", pursuers + np.array([0.04 * t / 0.2, 0, 0]), t)
        ctrl.update_team("evader", evaders, t)
    down = {"pursuer": np.array([True, False, False, False])}
    for obstacles in (np.zeros((0, 3)), np.array([[2.0, 0.5, 0.3], [-2.0, -0.5, 0.4]])):
        obs = ctrl.observe(obstacles, down)
        assert obs["pursuer"]["obstacles"].shape == (4, len(obstacles), 4)
        assert obs["pursuer"]["own"][0, 0] == 1 and obs["pursuer"]["own"][0, 4] == 0
        assert np.all(obs["evader"]["opponents"][:, 0, 0] == 1)
        assert np.all(obs["evader"]["opponents"][:, 0, 4:] == 0)
        # Every pursuer moved 4 cm along +x in 0.2 s: pursuer 2 (heading 0) forward at full
        # speed, pursuer 1 (heading pi) backing up.
        assert obs["pursuer"]["own"][2, 4] == pytest.approx(1.0, abs=1e-5)
        assert obs["pursuer"]["own"][1, 4] == pytest.approx(-1.0, abs=1e-5)
        commands = ctrl.act(obstacles, down)
        assert np.all(commands["pursuer"][0] == 0) and commands["evader"].shape == (2, 2)


def test_errors_are_clear():
    config = get_preset(ROBOTS)
    ctrl = Controller(config)
    ctrl.update("pursuer", 0, (0.0, 0.0, 0.0), 0.0)
    with pytest.raises(ValueError, match=r"no pose received yet for pursuers \[1, 2, 3\]"):
        ctrl.observe(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="out of range"):
        ctrl.update("evader", 2, (0.0, 0.0, 0.0), 0.0)
    with pytest.raises(ValueError, match="finite"):
        ctrl.update("evader", 0, (0.0, float("nan"), 0.0), 0.0)
    with pytest.raises(ValueError, match="unknown team"):
        Controller(config, {"referee": lambda obs, rng: jnp.zeros(1)})
    ctrl.update_team("pursuer", np.zeros((4, 3)), 1.0)
    ctrl.update_team("evader", np.ones((2, 3)), 1.0)
    with pytest.raises(ValueError, match="must have 4 flags"):
        ctrl.observe(np.zeros((0, 3)), {"pursuer": [True]})
    with pytest.raises(ValueError, match="r > 0"):
        ctrl.observe(np.array([[0.0, 0.0, -1.0]]))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda c: c.update("pursuer", 1.5, (0, 0, 0), 0.0), "index must be an integer, got 1.5"),
        (lambda c: c.update("pursuer", True, (0, 0, 0), 0.0), "index must be an integer"),
        (lambda c: c.update("pursuer", 0, (1.0, 2.0), 0.0), r"pursuer 0: pose must be \(x, y"),
        (lambda c: c.update("pursuer", 0, "here", 0.0), "pursuer 0: pose must be numbers"),
        (lambda c: c.update("pursuer", 0, (0, 0, 0), None), "pursuer 0: time must be seconds"),
        (lambda c: c.update_team("referee", [(0, 0, 0)], 0.0), "unknown team 'referee'"),
        (lambda c: c.update_team("pursuer", np.zeros((3, 3)), 0.0), r"must be \[4, 3\]"),
        (lambda c: c.update_team("pursuer", np.zeros((4, 3)), [0.0, 1.0]), "one time or 4"),
    ],
)
def test_a_wrong_type_or_shape_is_a_value_error_naming_the_robot(call, message):
    """Each was numpy's own words (or a KeyError, a TypeError) that named no robot."""
    with pytest.raises(ValueError, match=message):
        call(Controller(get_preset(ROBOTS)))


def test_a_preset_name_for_the_config_is_a_type_error():
    with pytest.raises(TypeError, match=r"EnvConfig \(e.g. pe_mjx.get_preset"):
        Controller("4-2-2")


def _placed(ctrl: Controller, pursuers, evaders, t: float = 0.0) -> None:
    ctrl.update_team("pursuer", pursuers, t)
    ctrl.update_team("evader", evaders, t)


PURSUERS = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, np.pi], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])
EVADERS = np.array([[0.0, 2.0, 0.0], [0.0, -2.0, 0.0]])
OBSTACLES = np.array([[2.0, 0.5, 0.3], [-2.0, -0.5, 0.4]])


def test_a_loaded_policy_commands_robots():
    """README's deployment example: `pe_mjx.load_policy(...)` (a `Policy`, which holds its
    parameters in dicts and cannot be hashed) in place of the exported file; `act` raised
    `TypeError: unhashable type: 'dict'`."""
    import pe_mjx

    config = get_preset(ROBOTS)
    policy = pe_mjx.load_policy("mix-20-5-8", team="pursuer", deterministic=True)
    ctrl = Controller(config, {"pursuer": policy})
    _placed(ctrl, PURSUERS, EVADERS)
    commands = ctrl.act(OBSTACLES, down={"pursuer": [False, True, False, False]})
    assert commands["pursuer"].shape == (4, 2) and np.all(commands["pursuer"][1] == 0)
    obs = ctrl.observe(OBSTACLES, down={"pursuer": [False, True, False, False]})
    actions = np.asarray(policy(obs["pursuer"], jax.random.key(0)))
    v, w = action_table(config.pursuer)
    np.testing.assert_array_equal(commands["pursuer"][0], [v[actions[0]], w[actions[0]]])


def test_poses_the_env_could_not_be_in_are_refused_naming_the_robot():
    config = get_preset(ROBOTS)  # arena radius 3 m, pursuer radius 0.1, evader 0.15
    ctrl = Controller(config, {t: make_policy("scripted", config, t) for t in TEAMS})
    cases = [
        ("pursuer", 2, (1e6, 0.0, 0.0), None, r"pursuer 2 at \(1e\+06, 0\) is outside the arena"),
        ("evader", 1, (0.0, -2.9, 0.0), None, r"evader 1 at \(0, -2\.9\) touches the arena wall"),
        ("pursuer", 0, (2.0, 0.65, 0.0), None, r"pursuer 0 at \(2, 0\.65\) overlaps obstacle 0"),
        ("pursuer", 3, (-0.9, 0.0, 0.0), None, r"pursuer 0 at \(-1, 0\) overlaps pursuer 3"),
        ("evader", 0, (1.1, 0.1, 0.0), None, r"pursuer 1 at \(1, 0\) overlaps evader 0"),
        # A robot that is down is where it went down: against what downed it, not far outside.
        ("pursuer", 2, (50.0, 0.0, 0.0), {"pursuer": [0, 0, 1, 0]}, "pursuer 2 .* outside"),
    ]
    for t, (team, i, pose, down, message) in enumerate(cases):
        pursuers, evaders = PURSUERS.copy(), EVADERS.copy()
        (pursuers if team == "pursuer" else evaders)[i] = pose
        _placed(ctrl, pursuers, evaders, t=float(t))  # a newer time: every pose is taken
        for call in (ctrl.observe, ctrl.act):
            with pytest.raises(ValueError, match=message):
                call(OBSTACLES, down)
    # Down robots may touch the wall, an obstacle, each other.
    pursuers = PURSUERS.copy()
    pursuers[0] = (-1.95, -0.35, 0.0)  # overlaps obstacle 1
    pursuers[2] = (0.0, 2.85, 0.0)  # touches the wall
    pursuers[3] = (0.05, 2.0, 0.0)  # overlaps evader 0, which is down too
    _placed(ctrl, pursuers, EVADERS, t=100.0)
    down = {"pursuer": [True, False, True, True], "evader": [True, False]}
    commands = ctrl.act(OBSTACLES, down)
    assert np.all(commands["pursuer"][[0, 2, 3]] == 0) and np.all(commands["evader"][0] == 0)
    # ... but an active robot may not touch a downed one.
    with pytest.raises(ValueError, match=r"pursuer 3 .* overlaps evader 0"):
        ctrl.act(OBSTACLES, {"pursuer": [True, False, True, False], "evader": [True, False]})


def test_a_policy_returning_impossible_actions_is_refused():
    config = get_preset(ROBOTS)
    ctrl = Controller(config, {"pursuer": lambda obs, rng: jnp.full(4, 999, jnp.int32)})
    _placed(ctrl, PURSUERS, EVADERS)
    with pytest.raises(ValueError, match=r"the pursuer policy returned int32\[4\] \[999"):
        ctrl.act(OBSTACLES)
