"""Procedural MJCF arenas built with `mujoco.MjSpec`: floor, wall, obstacles and unicycle robots.

Every robot body carries three joints (`slide x`, `slide y`, `hinge z`, in that order) driven by
three deadbeat `<velocity>` actuators, so `qpos[3 i : 3 i + 3]` is robot i's world pose (x, y,
yaw). Robots are ordered pursuers first, then evaders. MuJoCo contacts are disabled: collisions and
captures are detected analytically by the env (SPEC 2.2/2.3).

The env's physics model is built with `layout=None`: robots only, at the origin. `pe-mjx scene`
builds a model with a layout drawn by `env.reset`: robot bodies sit at their spawn pose and the
joint `ref`s equal that pose, so `qpos0` (what plain MuJoCo shows on load) is exactly the arena
that `env.reset` drew, and qpos stays the world pose. The slide axes are counter-rotated by the
spawn yaw so that they stay aligned with the world axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from xml.etree import ElementTree

import mujoco
import numpy as np

from pe_mjx.config import EnvConfig

ROBOT_HALF_HEIGHT = 0.05
WALL_HALF_HEIGHT = 0.15
WALL_THICKNESS = 0.05
WALL_SEGMENTS = 72
ROBOT_MASS = 1.0

TEAM_RGBA = {
    "pursuer": (0.85, 0.2, 0.15, 1.0),
    "evader": (0.15, 0.35, 0.9, 1.0),
}
OBSTACLE_RGBA = (0.45, 0.45, 0.45, 1.0)
WALL_RGBA = (0.3, 0.3, 0.35, 1.0)
MARKER_RGBA = (1.0, 1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Layout:
    """One drawn arena: numpy arrays, as `env.reset` produced them."""

    pursuer: np.ndarray
    """[P, 3] x, y, yaw."""
    evader: np.ndarray
    """[E, 3] x, y, yaw."""
    obstacles: np.ndarray
    """[K, 3] x, y, radius."""


def robot_name(team: str, index: int) -> str:
    return f"{team}_{index}"


def _cylinder_inertia(radius: float) -> list[float]:
    m, h = ROBOT_MASS, 2 * ROBOT_HALF_HEIGHT
    ixx = m * (3 * radius**2 + h**2) / 12
    return [ixx, ixx, m * radius**2 / 2]


def _add_robot(
    spec: mujoco.MjSpec, config: EnvConfig, team: str, index: int, pose: np.ndarray | None
) -> None:
    team_cfg = config.team(team)
    x, y, yaw = (0.0, 0.0, 0.0) if pose is None else (float(v) for v in pose)
    name = robot_name(team, index)
    body = spec.worldbody.add_body(name=name, pos=[x, y, ROBOT_HALF_HEIGHT])
    body.quat = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    inertia = _cylinder_inertia(team_cfg.radius)
    # Slide axes in the body frame, counter-rotated so that they point along world x and y.
    c, s = math.cos(yaw), math.sin(yaw)
    axes = {"x": [c, -s, 0.0], "y": [s, c, 0.0]}
    for axis_name, ref in (("x", x), ("y", y)):
        body.add_joint(
            name=f"{name}_{axis_name}",
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=axes[axis_name],
            ref=ref,
        )
    body.add_joint(name=f"{name}_yaw", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1], ref=yaw)
    body.add_geom(
        name=f"{name}_body",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[team_cfg.radius, ROBOT_HALF_HEIGHT, 0],
        rgba=TEAM_RGBA[team],
        contype=0,
        conaffinity=0,
        mass=ROBOT_MASS,
    )
    body.add_geom(
        name=f"{name}_heading",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=[0.6 * team_cfg.radius, 0, ROBOT_HALF_HEIGHT],
        size=[0.35 * team_cfg.radius, 0.15 * team_cfg.radius, 0.01],
        rgba=MARKER_RGBA,
        contype=0,
        conaffinity=0,
        mass=0,
    )
    # Deadbeat velocity servos: with gain kv = inertia / physics_dt, one semi-implicit Euler step
    # takes the joint velocity from whatever it was to exactly the command (qvel + dt kv (ctrl -
    # qvel) / inertia = ctrl), so the env's chord commands put every physics step on the
    # commanded arc (docs/design.md, "MJX actuation"); a lag made agents coast past the arc that
    # the action mask checked.
    dt = config.physics_dt
    for axis_name, gain in (
        ("x", ROBOT_MASS / dt),
        ("y", ROBOT_MASS / dt),
        ("yaw", inertia[2] / dt),
    ):
        act = spec.add_actuator(name=f"{name}_{axis_name}_vel", target=f"{name}_{axis_name}")
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_velocity(kv=gain)


def build_spec(
    config: EnvConfig, layout: Layout | None = None, visual: bool = True
) -> mujoco.MjSpec:
    """Builds the arena's MjSpec.

    Args:
      config: the game.
      layout: a drawn arena (robots at their spawn poses, obstacles placed); None puts every robot
        at the origin and leaves out the obstacles, whose radii are drawn per reset.
      visual: include floor and wall (static geoms that the analytic events use, not the physics).
    """
    spec = mujoco.MjSpec()
    spec.modelname = f"pe_mjx_{config.name}"
    spec.compiler.degree = False
    spec.option.timestep = config.physics_dt
    # What the game does not need is switched off (docs/benchmarks.md, MJX breakdown): no
    # contacts or constraints (events are analytic), no gravity, springs or dampers. Semi-implicit
    # Euler: implicitfast factorised a dense nv x nv matrix every physics step (nv = 3 per robot).
    # Sparse mass matrix: each robot's 3 x 3 block is independent (2x faster than dense at 20-5-8).
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.jacobian = mujoco.mjtJacobian.mjJAC_SPARSE
    spec.option.gravity = [0.0, 0.0, 0.0]
    disable = mujoco.mjtDisableBit
    for flag in (
        disable.mjDSBL_CONTACT,
        disable.mjDSBL_CONSTRAINT,
        disable.mjDSBL_GRAVITY,
        disable.mjDSBL_SPRING,
        disable.mjDSBL_DAMPER,
        disable.mjDSBL_EULERDAMP,
    ):
        spec.option.disableflags |= flag
    spec.visual.global_.offwidth = 1280
    spec.visual.global_.offheight = 960
    radius = config.arena.radius
    if visual:
        spec.worldbody.add_light(pos=[0, 0, 3 * radius], dir=[0, 0, -1], castshadow=0)
        spec.worldbody.add_geom(
            name="floor",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[radius + 1, radius + 1, 0.1],
            rgba=[0.92, 0.92, 0.88, 1],
            contype=0,
            conaffinity=0,
        )
        # The wall: thin boxes on the rim, their inner faces tangent to the circle of radius R.
        half_len = (radius + WALL_THICKNESS) * math.tan(math.pi / WALL_SEGMENTS)
        for k in range(WALL_SEGMENTS):
            a = 2 * math.pi * k / WALL_SEGMENTS
            rr = radius + WALL_THICKNESS / 2
            spec.worldbody.add_geom(
                name=f"wall_{k}",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                pos=[rr * math.cos(a), rr * math.sin(a), WALL_HALF_HEIGHT],
                quat=[math.cos(a / 2), 0, 0, math.sin(a / 2)],
                size=[WALL_THICKNESS / 2, half_len, WALL_HALF_HEIGHT],
                rgba=WALL_RGBA,
                contype=0,
                conaffinity=0,
            )
    if layout is not None:
        for k, (x, y, r) in enumerate(np.asarray(layout.obstacles, dtype=float)):
            spec.worldbody.add_geom(
                name=f"obstacle_{k}",
                type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                pos=[x, y, WALL_HALF_HEIGHT],
                size=[r, WALL_HALF_HEIGHT, 0],
                rgba=OBSTACLE_RGBA,
                contype=0,
                conaffinity=0,
            )
    for team in ("pursuer", "evader"):
        poses = None if layout is None else np.asarray(getattr(layout, team), dtype=float)
        for i in range(config.team(team).num_agents):
            _add_robot(spec, config, team, i, None if poses is None else poses[i])
    if layout is not None:
        qpos = np.concatenate([layout.pursuer, layout.evader]).reshape(-1)
        spec.add_key(name="spawn", qpos=qpos.tolist())
    return spec


def build_model(
    config: EnvConfig, layout: Layout | None = None, visual: bool = True
) -> mujoco.MjModel:
    """Compiles `build_spec`."""
    return build_spec(config, layout, visual).compile()


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _exact_attributes(config: EnvConfig, layout: Layout) -> dict[tuple[str, str], dict[str, str]]:
    """The layout-dependent attributes of `build_spec`, printed at full (round-trip) precision."""
    exact: dict[tuple[str, str], dict[str, str]] = {}
    for team in ("pursuer", "evader"):
        for i, pose in enumerate(np.asarray(getattr(layout, team), dtype=float)):
            name = robot_name(team, i)
            x, y, yaw = (float(v) for v in pose)
            c, s = math.cos(yaw), math.sin(yaw)
            exact["body", name] = {
                "pos": _fmt([x, y, ROBOT_HALF_HEIGHT]),
                "quat": _fmt([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]),
            }
            exact["joint", f"{name}_x"] = {"ref": _fmt([x]), "axis": _fmt([c, -s, 0.0])}
            exact["joint", f"{name}_y"] = {"ref": _fmt([y]), "axis": _fmt([s, c, 0.0])}
            exact["joint", f"{name}_yaw"] = {"ref": _fmt([yaw])}
    for k, (x, y, r) in enumerate(np.asarray(layout.obstacles, dtype=float)):
        exact["geom", f"obstacle_{k}"] = {
            "pos": _fmt([x, y, WALL_HALF_HEIGHT]),
            "size": _fmt([r, WALL_HALF_HEIGHT]),
        }
    qpos = np.concatenate([layout.pursuer, layout.evader]).reshape(-1)
    exact["key", "spawn"] = {"qpos": _fmt(qpos)}
    return exact


def scene_xml(config: EnvConfig, layout: Layout) -> str:
    """Standalone MJCF of one drawn arena (loads in plain MuJoCo).

    MuJoCo's XML writer prints 6 significant digits; the layout's numbers (poses, obstacles, the
    spawn key) are rewritten at full precision, so the file loads to exactly the drawn arena.
    """
    root = ElementTree.fromstring(build_spec(config, layout, visual=True).to_xml())
    exact = _exact_attributes(config, layout)
    for elem in root.iter():
        attributes = exact.get((elem.tag, elem.get("name", "")))
        if attributes:
            elem.attrib.update(attributes)
    return ElementTree.tostring(root, encoding="unicode") + "\n"
