"""The trajectory file format: round trip, validation with clear errors, no pickle, no overwrite."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.env import CAPTURE
from pe_mjx.trajectory import (
    FORMAT_VERSION,
    Trajectory,
    TrajectoryError,
    from_episodes,
    load,
    save,
)

PRESET = "2-1-1"  # 3 agents, 1 obstacle


def make(frames: int = 5, arenas: int = 2, cause: bool = True) -> Trajectory:
    config = get_preset(PRESET)
    rng = np.random.default_rng(0)
    poses = rng.uniform(-1, 1, (frames, arenas, 3, 3)).astype(np.float32)
    active = np.ones((frames, arenas, 3), bool)
    active[3:, 0, [0, 2]] = False
    causes = np.where(active, 0, CAPTURE).astype(np.int32)
    obstacles = np.asarray([[[0.5, 0.5, 0.3]]] * arenas, np.float32)
    return Trajectory(
        config=config,
        poses=poses,
        active=active,
        obstacles=obstacles,
        cause=causes if cause else None,
        meta={"pursuer": "scripted", "seed": 3},
    )


def raw(traj: Trajectory) -> dict[str, np.ndarray]:
    return {
        "format": np.asarray(FORMAT_VERSION),
        "config_json": np.asarray(traj.config.to_json()),
        "poses": traj.poses,
        "active": traj.active,
        "obstacles": traj.obstacles,
    }


def test_round_trip(tmp_path):
    traj = make()
    path = save(tmp_path / "t.npz", traj)
    back = load(path)
    assert back.config == traj.config
    np.testing.assert_array_equal(back.poses, traj.poses)
    np.testing.assert_array_equal(back.active, traj.active)
    np.testing.assert_array_equal(back.cause, traj.cause)
    np.testing.assert_array_equal(back.obstacles, traj.obstacles)
    assert back.meta == traj.meta
    assert (back.num_frames, back.num_arenas) == (5, 2)


def test_cause_is_optional(tmp_path):
    back = load(save(tmp_path / "t.npz", make(cause=False)))
    assert back.cause is None
    causes = back.causes()
    assert causes.shape == back.active.shape
    assert np.all(causes[back.active] == 0) and np.all(causes[~back.active] == -1)


def test_save_refuses_to_overwrite_and_wrong_suffix(tmp_path):
    path = save(tmp_path / "t.npz", make())
    before = path.read_bytes()
    with pytest.raises(TrajectoryError, match="exists"):
        save(path, make(frames=3))
    assert path.read_bytes() == before
    with pytest.raises(TrajectoryError, match=r"\.npz"):
        save(tmp_path / "t.bin", make())


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"poses": np.zeros((5, 2, 4, 3), np.float32)}, r"poses has shape \[5, 2, 4, 3\]"),
        ({"poses": np.zeros((5, 2, 3, 3), np.int32)}, "poses has dtype int32"),
        ({"active": np.ones((5, 2, 3), np.int8)}, "active has dtype int8"),
        ({"active": np.ones((4, 2, 3), bool)}, r"active has shape \[4, 2, 3\]"),
        ({"obstacles": np.zeros((2, 2, 3), np.float32)}, "obstacles has shape"),
        ({"cause": np.full((5, 2, 3), 9, np.int32)}, "cause must hold codes"),
        ({"cause": np.zeros((5, 2, 3), np.float32)}, "cause has dtype float32"),
    ],
)
def test_validation_names_the_key(change, message):
    with pytest.raises(TrajectoryError, match=message):
        dataclasses.replace(make(), **change)


def test_cause_must_match_active():
    traj = make()
    cause = traj.cause.copy()
    cause[0, 0, 0] = CAPTURE
    with pytest.raises(TrajectoryError, match="exactly where active"):
        dataclasses.replace(traj, cause=cause)


def test_nan_poses_rejected():
    traj = make()
    poses = traj.poses.copy()
    poses[1, 0, 0, 0] = np.nan
    with pytest.raises(TrajectoryError, match="NaN"):
        dataclasses.replace(traj, poses=poses)


def test_load_errors_name_file_and_key(tmp_path):
    missing = tmp_path / "missing.npz"
    with pytest.raises(TrajectoryError, match="no such file"):
        load(missing)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip")
    with pytest.raises(TrajectoryError, match=r"not a readable \.npz"):
        load(garbage)
    arrays = raw(make())
    del arrays["poses"]
    np.savez(tmp_path / "nokey.npz", **arrays)
    with pytest.raises(TrajectoryError, match=r"nokey.npz: missing keys \['poses'\]"):
        load(tmp_path / "nokey.npz")
    arrays = raw(make())
    arrays["extra"] = np.zeros(1)
    np.savez(tmp_path / "extra.npz", **arrays)
    with pytest.raises(TrajectoryError, match="unknown keys"):
        load(tmp_path / "extra.npz")
    arrays = raw(make())
    arrays["config_json"] = np.asarray('{"name": 3}')
    np.savez(tmp_path / "config.npz", **arrays)
    with pytest.raises(TrajectoryError, match="config_json"):
        load(tmp_path / "config.npz")
    arrays = raw(make())
    arrays["format"] = np.asarray(99)
    np.savez(tmp_path / "format.npz", **arrays)
    with pytest.raises(TrajectoryError, match="format is 99"):
        load(tmp_path / "format.npz")
    arrays = raw(make())
    arrays["poses"] = arrays["poses"][:, :, :2]
    np.savez(tmp_path / "shape.npz", **arrays)
    with pytest.raises(TrajectoryError, match=r"shape.npz: poses has shape"):
        load(tmp_path / "shape.npz")


def test_pickled_arrays_are_refused(tmp_path):
    arrays = raw(make())
    arrays["meta_json"] = np.asarray([{"evil": 1}], dtype=object)
    np.savez(tmp_path / "pickle.npz", **arrays)
    with pytest.raises(TrajectoryError, match=r"pickle\.npz"):
        load(tmp_path / "pickle.npz")


def test_select_and_from_episodes():
    traj = make(arenas=3)
    assert traj.select(2).num_arenas == 2
    assert traj.select(10).num_arenas == 3

    @dataclasses.dataclass
    class World:
        cause: np.ndarray
        obstacles: np.ndarray

    @dataclasses.dataclass
    class State:
        world: World

    final = State(World(cause=traj.cause[-1], obstacles=traj.obstacles))
    rebuilt = from_episodes(traj.config, {"poses": traj.poses, "active": traj.active}, final)
    np.testing.assert_array_equal(rebuilt.cause, traj.cause)


def test_recorded_episodes_round_trip(tmp_path):
    """The evaluator's path: play_episodes(record=True) -> from_episodes -> save -> load."""
    import jax

    from pe_mjx.config import TEAMS
    from pe_mjx.env import PursuitEvasionEnv
    from pe_mjx.episodes import play_episodes
    from pe_mjx.policies import make_policy

    config = get_preset(PRESET).replace(max_steps=12)
    env = PursuitEvasionEnv(config, backend="kinematic")
    policies = {t: make_policy("random", config, t) for t in TEAMS}
    keys = jax.random.split(jax.random.key(0), 2)
    final, record = jax.jit(lambda k: play_episodes(env, policies, k, record=True))(keys)
    traj = from_episodes(config, record, final, {"pursuer": "random"})
    back = load(save(tmp_path / "pairing-0.npz", traj))
    assert back.poses.shape == (13, 2, 3, 3)
    np.testing.assert_array_equal(back.cause[-1], np.asarray(final.world.cause))
    np.testing.assert_array_equal(back.obstacles, np.asarray(final.world.obstacles))
    np.testing.assert_allclose(back.poses[-1, :, :, :2], np.asarray(final.world.pos), atol=1e-6)
