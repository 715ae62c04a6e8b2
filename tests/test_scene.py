"""The procedural MJCF (SPEC 2.2): joints, actuators, options, world-aligned slides."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from pe_mjx import scene
from pe_mjx.config import get_preset


def _yaw(xmat: np.ndarray) -> float:
    m = np.asarray(xmat).reshape(3, 3)
    return math.atan2(m[1, 0], m[0, 0])


def test_physics_model_layout_and_options():
    cfg = get_preset("4-1-2")
    model = scene.build_model(cfg, layout=None, visual=False)
    n = cfg.num_agents
    assert (model.nq, model.nv, model.nu, model.njnt) == (3 * n, 3 * n, 3 * n, 3 * n)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert model.opt.jacobian == mujoco.mjtJacobian.mjJAC_SPARSE
    assert model.opt.timestep == pytest.approx(cfg.physics_dt)
    np.testing.assert_array_equal(model.opt.gravity, 0.0)
    for flag in ("CONTACT", "CONSTRAINT", "GRAVITY", "SPRING", "DAMPER", "EULERDAMP"):
        assert model.opt.disableflags & getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag}"), flag
    expected_types = [mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_SLIDE]
    expected_types.append(mujoco.mjtJoint.mjJNT_HINGE)
    names = [scene.robot_name("pursuer", i) for i in range(4)] + [scene.robot_name("evader", 0)]
    for i, name in enumerate(names):
        for k, suffix in enumerate(("x", "y", "yaw")):
            j = 3 * i + k
            assert model.joint(j).name == f"{name}_{suffix}"
            assert model.jnt_type[j] == expected_types[k]
            assert model.jnt_qposadr[j] == j
            assert model.actuator_trnid[j, 0] == j
            # velocity actuator: gain kv, bias -kv * qvel
            assert model.actuator_gainprm[j, 0] > 0
            assert model.actuator_biasprm[j, 2] == pytest.approx(-model.actuator_gainprm[j, 0])
        radius = cfg.pursuer.radius if name.startswith("pursuer") else cfg.evader.radius
        assert model.geom(f"{name}_body").size[0] == pytest.approx(radius)
    # no obstacles nor wall in the physics model
    assert all(not model.geom(g).name.startswith(("obstacle", "wall")) for g in range(model.ngeom))


def test_velocity_actuators_track_world_velocity_for_rotated_body():
    """In plain MuJoCo a robot spawned with a yaw moves along world x for ctrl (v, 0, 0); the
    actuators are deadbeat: after one physics step the joint velocity is the command, whatever it
    was, so the pose advances by exactly dt * ctrl."""
    cfg = get_preset("2-1-1").replace(physics_dt=0.05)
    layout = scene.Layout(
        pursuer=np.array([[0.3, -0.2, 1.1], [-0.5, 0.5, -2.5]]),
        evader=np.array([[0.0, 0.8, 3.0]]),
        obstacles=np.array([[1.0, -1.0, 0.4]]),
    )
    model = scene.build_model(cfg, layout)
    dt = model.opt.timestep
    data = mujoco.MjData(model)
    data.qvel[:] = np.random.default_rng(0).uniform(-1, 1, model.nv)  # any previous velocity
    mujoco.mj_forward(model, data)
    body = model.body("pursuer_0").id
    start = data.xpos[body].copy()
    yaw0 = _yaw(data.xmat[body])
    for ctrl in ([0.1, 0.0, 0.0], [-0.05, 0.2, 0.0], [0.0, 0.0, 0.5]):
        data.ctrl[:3] = ctrl
        qpos = data.qpos[:3].copy()
        mujoco.mj_step(model, data)
        np.testing.assert_allclose(data.qvel[:3], ctrl, atol=1e-12)
        np.testing.assert_allclose(data.qpos[:3], qpos + dt * np.asarray(ctrl), atol=1e-12)
    data.ctrl[:3] = [0.1, 0.0, 0.0]
    for _ in range(round(2 / dt)):  # 2 s
        mujoco.mj_step(model, data)
    mujoco.mj_forward(model, data)  # xpos of the final qpos
    moved = data.xpos[body] - start - dt * np.array([0.1 - 0.05, 0.2, 0.0])
    assert moved[0] == pytest.approx(0.2, abs=1e-9)
    assert abs(moved[1]) < 1e-9 and abs(moved[2]) < 1e-9
    assert _yaw(data.xmat[body]) == pytest.approx(yaw0 + 0.5 * dt, abs=1e-9)
    # qpos stays the world pose
    assert data.qpos[0] == pytest.approx(data.xpos[body][0], abs=1e-9)
    data.ctrl[:3] = [0.0, 0.0, 0.5]
    for _ in range(round(1 / dt)):  # 1 s
        mujoco.mj_step(model, data)
    mujoco.mj_forward(model, data)
    assert data.qpos[2] == pytest.approx(1.1 + 0.5 * dt + 0.5, abs=1e-9)
    assert math.cos(_yaw(data.xmat[body]) - data.qpos[2]) == pytest.approx(1.0, abs=1e-9)


def test_scene_xml_loads_and_has_layout():
    cfg = get_preset("2-1-1")
    layout = scene.Layout(
        pursuer=np.array([[0.3, -0.2, 1.1], [-0.5, 0.5, -2.5]]),
        evader=np.array([[0.0, 0.8, 3.0]]),
        obstacles=np.array([[1.0, -1.0, 0.4]]),
    )
    model = mujoco.MjModel.from_xml_string(scene.scene_xml(cfg, layout))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    poses = np.concatenate([layout.pursuer, layout.evader])
    np.testing.assert_allclose(model.qpos0, poses.reshape(-1), atol=1e-9)
    np.testing.assert_allclose(model.key("spawn").qpos, poses.reshape(-1), atol=1e-9)
    for i, name in enumerate(["pursuer_0", "pursuer_1", "evader_0"]):
        body = model.body(name).id
        np.testing.assert_allclose(data.xpos[body][:2], poses[i, :2], atol=1e-9)
        assert math.cos(_yaw(data.xmat[body]) - poses[i, 2]) == pytest.approx(1.0, abs=1e-9)
    geom = model.geom("obstacle_0")
    np.testing.assert_allclose(geom.pos[:2], [1.0, -1.0])
    assert geom.size[0] == pytest.approx(0.4)
    walls = [g for g in range(model.ngeom) if model.geom(g).name.startswith("wall_")]
    assert len(walls) == scene.WALL_SEGMENTS
    # inner faces of the wall lie on the arena circle
    for g in walls[:5]:
        centre = np.linalg.norm(model.geom_pos[g][:2])
        assert centre - model.geom_size[g][0] == pytest.approx(cfg.arena.radius, abs=1e-5)
