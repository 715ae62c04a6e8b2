"""`pe_mjx.export`: the standalone MJCF loads in plain MuJoCo and is exactly `env.reset`'s arena."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from pe_mjx import export, scene
from pe_mjx.config import get_preset
from tests.conftest import first

PRESET, SEED = "4-1-2", 3


@pytest.fixture(scope="module")
def loaded():
    model = mujoco.MjModel.from_xml_string(export.arena_xml(PRESET, SEED))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


@pytest.mark.parametrize("backend", ["kinematic", "mjx"])
def test_arena_xml_matches_reset(loaded, get_compiled, backend):
    model, data = loaded
    c = get_compiled(PRESET, backend)
    # batch_reset (shared with the contract tests) on [key(SEED), key(SEED + 1)]
    keys = jnp.stack([jax.random.key(SEED), jax.random.key(SEED + 1)])
    state = first(c.batch_reset(keys))
    poses = c.env.poses(state)
    expected = np.concatenate([np.asarray(poses["pursuer"]), np.asarray(poses["evader"])])
    # exact: the XML carries the float32 values at full precision
    np.testing.assert_array_equal(model.qpos0, expected.reshape(-1).astype(np.float64))
    np.testing.assert_array_equal(model.key("spawn").qpos, model.qpos0)
    np.testing.assert_array_equal(data.qpos, model.qpos0)
    names = [scene.robot_name("pursuer", i) for i in range(c.env.num_pursuers)]
    names += [scene.robot_name("evader", i) for i in range(c.env.num_evaders)]
    for i, name in enumerate(names):
        body = model.body(name).id
        np.testing.assert_allclose(data.xpos[body][:2], expected[i, :2], atol=1e-12)
        m = data.xmat[body].reshape(3, 3)
        yaw = math.atan2(m[1, 0], m[0, 0])
        assert math.cos(yaw - expected[i, 2]) == pytest.approx(1.0, abs=1e-9)
        assert math.sin(yaw - expected[i, 2]) == pytest.approx(0.0, abs=1e-12)
    obstacles = np.asarray(c.env.obstacles(state))
    assert obstacles.shape == (c.env.num_obstacles, 3)
    for k, (x, y, r) in enumerate(obstacles):
        geom = model.geom(f"obstacle_{k}")
        assert geom.type[0] == mujoco.mjtGeom.mjGEOM_CYLINDER
        np.testing.assert_array_equal(geom.pos[:2], np.float64([x, y]))
        assert geom.size[0] == np.float64(r)
    assert not any(model.geom(g).name == f"obstacle_{len(obstacles)}" for g in range(model.ngeom))


def test_layout_equals_reset_and_depends_on_seed(get_compiled):
    """scene_xml of a hand-made Layout and arena_layout agree with the batched reset."""
    c = get_compiled(PRESET, "kinematic")
    keys = jnp.stack([jax.random.key(SEED), jax.random.key(SEED + 1)])
    states = c.batch_reset(keys)
    pos, yaw = np.asarray(states.world.pos), np.asarray(states.world.yaw)
    poses = np.concatenate([pos, yaw[..., None]], axis=-1)
    p = c.env.num_pursuers
    layouts = [
        scene.Layout(
            pursuer=poses[b, :p],
            evader=poses[b, p:],
            obstacles=np.asarray(states.world.obstacles[b]),
        )
        for b in range(2)
    ]
    xml = scene.scene_xml(get_preset(PRESET), layouts[0])
    assert xml == export.scene_xml(get_preset(PRESET), layouts[0])
    assert not np.allclose(layouts[1].obstacles, layouts[0].obstacles)
    assert scene.scene_xml(get_preset(PRESET), layouts[1]) != xml


def test_exported_model_steps_in_plain_mujoco(loaded):
    model, _ = loaded
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("spawn").id)
    data.ctrl[:] = 0.05
    for _ in range(10):
        mujoco.mj_step(model, data)
    assert np.all(np.isfinite(data.qpos))
    assert data.ncon == 0
