"""The trajectory file format: round trip, validation with clear errors, no pickle, no overwrite."""

from __future__ import annotations

import dataclasses
import io
import zipfile

import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.names import CAPTURE
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
    poses[3:, 0, [0, 2]] = poses[min(3, frames - 1), 0, [0, 2]]  # the downed stay where they fell
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


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("config_json", "[" * 100_000 + "]" * 100_000, "config_json is JSON nested too deeply"),
        ("meta_json", "[" * 100_000 + "]" * 100_000, "meta_json is JSON nested too deeply"),
        ("poses", 1e30, r"poses holds a position 1e\+30 m from the centre, beyond the 26 m"),
        ("obstacles", 1e30, r"obstacles holds a position 1e\+30 m"),
        ("obstacles", -0.5, "obstacles holds a negative radius"),
    ],
)
def test_crafted_contents_are_refused_naming_the_key(tmp_path, key, value, message):
    """Deep JSON was a RecursionError traceback; a position far outside the arena (or a
    negative obstacle) was drawn as an empty arena without a word."""
    arrays = raw(make())
    if key.endswith("_json"):
        arrays[key] = np.asarray(value)
    elif key == "poses":
        arrays["poses"] = arrays["poses"].copy()
        arrays["poses"][:, 1, 1, 0] = value  # arena 1, agent 1 (never downed): every frame
    elif value < 0:
        arrays["obstacles"] = arrays["obstacles"].copy()
        arrays["obstacles"][0, 0, 2] = value
    else:
        arrays["obstacles"] = arrays["obstacles"].copy()
        arrays["obstacles"][0, 0, 0] = value
    np.savez(tmp_path / "crafted.npz", **arrays)
    with pytest.raises(TrajectoryError, match=r"crafted\.npz: " + message):
        load(tmp_path / "crafted.npz")


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

    from pe_mjx.env import PursuitEvasionEnv
    from pe_mjx.episodes import play_episodes
    from pe_mjx.names import TEAMS
    from pe_mjx.policy.scripted import make_policy

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


def npy_bytes(dtype: str, shape: tuple[int, ...], data: bytes = b"") -> bytes:
    """A .npy member whose header declares `dtype` and `shape`, followed by `data`."""
    header = repr({"descr": dtype, "fortran_order": False, "shape": shape}).encode()
    header += b" " * (63 - (len(header) + 10) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + data


def write_npz(path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for key, payload in members.items():
            zf.writestr(f"{key}.npy", payload)


def npz_members(traj: Trajectory) -> dict[str, bytes]:
    out = {}
    for key, array in raw(traj).items():
        buf = io.BytesIO()
        np.save(buf, array, allow_pickle=False)
        out[key] = buf.getvalue()
    return out


def test_a_header_claiming_terabytes_is_refused_before_any_allocation(tmp_path):
    """The 12 KB file whose poses header claims 3.27 TiB: one clear error, no MemoryError."""
    members = npz_members(make())
    members["poses"] = npy_bytes("<f4", (1_000_000, 100_000, 3, 3), b"\0" * 12_000)
    write_npz(tmp_path / "huge.npz", members)
    assert (tmp_path / "huge.npz").stat().st_size < 20_000
    with pytest.raises(TrajectoryError, match=r"huge\.npz: poses declares 3,600,000,000,000 bytes"):
        load(tmp_path / "huge.npz")


@pytest.mark.parametrize(
    ("key", "payload", "message"),
    [
        ("poses", npy_bytes("<f4", (5, 2, 3, 3), b"\0" * 16), "poses is damaged: its header"),
        ("active", npy_bytes("<f4", (5, 2, 3), b"\0" * 120), "active has dtype float32"),
        ("poses", npy_bytes("<f4", (5, 2, 3), b"\0" * 120), "poses has 3 dimensions"),
        ("obstacles", npy_bytes("|O", (2, 1, 3)), "obstacles holds Python objects"),
        ("cause", npy_bytes("<i4", (5, 2, 4), b"\0" * 160), r"cause has shape \[5, 2, 4\]"),
        ("config_json", npy_bytes("<U2000000", ()), "config_json is longer than"),
        ("format", b"\x93NUMPY\x09\x00garbage", "format is not a readable .npy array"),
        ("poses", npy_bytes("<f4", (0, 2, 3, 3)), "poses holds 0 frames"),
    ],
)
def test_damaged_members_are_one_clear_error(tmp_path, key, payload, message):
    members = npz_members(make())
    members[key] = payload
    write_npz(tmp_path / "bad.npz", members)
    with pytest.raises(TrajectoryError, match=message):
        load(tmp_path / "bad.npz")


def test_a_forged_zip_entry_size_is_refused(tmp_path):
    """The zip directory claims far more than deflate can expand to: refused before reading."""
    write_npz(tmp_path / "t.npz", npz_members(make()))
    data = bytearray((tmp_path / "t.npz").read_bytes())
    pos = data.find(b"PK\x01\x02")  # the central directory's records
    while data[pos + 46 : pos + 46 + int.from_bytes(data[pos + 28 : pos + 30], "little")] != (
        b"poses.npy"
    ):
        pos = data.find(b"PK\x01\x02", pos + 4)
    data[pos + 24 : pos + 28] = (2**31).to_bytes(4, "little")  # its uncompressed size
    (tmp_path / "t.npz").write_bytes(bytes(data))
    with pytest.raises(TrajectoryError, match=r"t\.npz: poses is damaged: its zip entry claims"):
        load(tmp_path / "t.npz")


def test_truncated_file_is_one_clear_error(tmp_path):
    path = save(tmp_path / "t.npz", make())
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(TrajectoryError, match=r"t\.npz: not a readable \.npz"):
        load(path)


def broken_rule(rule: str) -> dict[str, np.ndarray]:
    traj = make()
    poses, active, cause = traj.poses.copy(), traj.active.copy(), traj.cause.copy()
    if rule == "moves":
        poses[4, 0, 2, 0] += 0.01  # evader 2 of arena 0 is down since frame 3
    elif rule == "returns":
        active[4, 0, 0] = True
        cause[4, 0, 0] = 0
    else:
        cause[4, 0, 0] = 2
    return {"poses": poses, "active": active, "cause": cause}


@pytest.mark.parametrize(
    ("rule", "message"),
    [
        ("moves", r"poses break the rules: a downed agent moves \(frame 4, arena 0, agent 2\)"),
        ("returns", r"active breaks the rules: a downed agent is active again \(frame 4"),
        ("cause", r"cause breaks the rules: a downed agent's cause changes \(frame 4"),
    ],
)
def test_replays_that_break_the_rules_are_refused(tmp_path, rule, message):
    changes = broken_rule(rule)
    with pytest.raises(TrajectoryError, match=message):
        dataclasses.replace(make(), **changes)
    arrays = raw(make()) | changes
    np.savez(tmp_path / "rule.npz", **arrays)
    with pytest.raises(TrajectoryError, match=r"rule\.npz: " + message):
        load(tmp_path / "rule.npz")
