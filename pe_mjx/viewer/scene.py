"""Config and state -> Viser scene: one batched handle per kind of body, updated atomically.

`ArenaScene` draws B arenas of one `EnvConfig` side by side in a grid. Static bodies (floor, wall)
are sent once; every frame (`Frame`: poses, active flags, causes, obstacles of all arenas) updates
the batched handles of the obstacles, both teams' robots, their heading markers, the
incapacitation markers, the trails and the attention overlay inside one ``server.atomic()`` block,
so a browser never shows half a frame. The geometry matches `pe_mjx.scene` (the MJCF arena): robot
and obstacle radii, wall and robot heights, team colours.

The array helpers (`grid_offsets`, `yaw_to_wxyz`, `trail_segments`, `attention_bars`, ...) are pure
numpy so that they are tested without a browser.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from pe_mjx import scene as mjcf
from pe_mjx.config import EnvConfig
from pe_mjx.names import CAPTURE, OBSTACLE, OPPONENT, TEAMMATE, TEAMS, WALL

ARENA_GAP = 1.0
"""Metres between the walls of neighbouring arenas in the grid."""
FLOOR_MARGIN = 0.3
TRAIL_Z = 0.005
MARKER_Z = 2 * mjcf.ROBOT_HALF_HEIGHT + 0.12
ATTENTION_Z = 2 * mjcf.ROBOT_HALF_HEIGHT + 0.03
ATTENTION_MIN_WEIGHT = 0.005
"""Attention weights below this are not drawn."""
ATTENTION_WIDTH = (0.015, 0.4)
"""Bar width in metres: base + slope * weight (weights of all tokens sum to 1)."""
CAMERA_FOV = math.radians(75.0)
"""viser's default vertical field of view."""


def _rgb(rgba: tuple[float, ...]) -> tuple[int, int, int]:
    return tuple(round(255 * c) for c in rgba[:3])  # type: ignore[return-value]


TEAM_RGB = {team: _rgb(mjcf.TEAM_RGBA[team]) for team in TEAMS}
OBSTACLE_RGB = _rgb(mjcf.OBSTACLE_RGBA)
WALL_RGB = _rgb(mjcf.WALL_RGBA)
MARKER_RGB = _rgb(mjcf.MARKER_RGBA)
FLOOR_RGB = (235, 235, 224)
INACTIVE_RGB = (150, 150, 150)
CAUSE_RGB = {
    WALL: (255, 140, 0),
    OBSTACLE: (120, 70, 30),
    CAPTURE: (255, 215, 0),
    TEAMMATE: (160, 60, 200),
    OPPONENT: (230, 0, 140),
}
"""Colour of the marker above an incapacitated agent, per `env.World.cause` code."""
UNKNOWN_CAUSE_RGB = (20, 20, 20)
ATTENTION_RGB = {
    "teammates": (30, 170, 70),
    "opponents": (255, 150, 0),
    "obstacles": (140, 60, 210),
}


@dataclasses.dataclass(frozen=True)
class Frame:
    """What one instant of B arenas looks like (numpy)."""

    poses: np.ndarray
    """[B, N, 3] x, y, yaw of all agents, pursuers first."""
    active: np.ndarray
    """bool [B, N]."""
    cause: np.ndarray
    """int [B, N]: `env.World.cause` (0 while active, -1 where unknown)."""
    obstacles: np.ndarray
    """[B, K, 3] x, y, radius."""


@dataclasses.dataclass(frozen=True)
class AttentionOverlay:
    """The attention of one agent, as lines from it to the entities it attends to."""

    arena: int
    agent: int
    """Global agent index (pursuers first)."""
    targets: np.ndarray
    """[M, 2] world positions of the attended entities (arena frame)."""
    weights: np.ndarray
    """[M] attention weights (mean over heads)."""
    kinds: tuple[str, ...]
    """[M] "teammates", "opponents" or "obstacles"."""


# ----------------------------------------------------------------------------- numpy helpers


def grid_offsets(num_arenas: int, arena_radius: float, gap: float = ARENA_GAP) -> np.ndarray:
    """[B, 2] centres of B arenas in a near-square grid, row-major, centred on the origin."""
    cols = max(1, math.ceil(math.sqrt(num_arenas)))
    rows = max(1, math.ceil(num_arenas / cols))
    pitch = 2 * (arena_radius + mjcf.WALL_THICKNESS) + gap
    idx = np.arange(num_arenas)
    x = (idx % cols - (cols - 1) / 2) * pitch
    y = ((rows - 1) / 2 - idx // cols) * pitch
    return np.stack([x, y], axis=-1).astype(np.float32)


def yaw_to_wxyz(yaw: np.ndarray) -> np.ndarray:
    """[..., 4] quaternions (w, x, y, z) of rotations by `yaw` about +z."""
    half = 0.5 * np.asarray(yaw, dtype=np.float32)
    zero = np.zeros_like(half)
    return np.stack([np.cos(half), zero, zero, np.sin(half)], axis=-1)


def robot_colors(team_rgb: tuple[int, int, int], active: np.ndarray) -> np.ndarray:
    """uint8 [M, 3]: the team colour, grey where inactive."""
    active = np.asarray(active, dtype=bool).reshape(-1)
    out = np.empty((active.size, 3), dtype=np.uint8)
    out[:] = team_rgb
    out[~active] = INACTIVE_RGB
    return out


def cause_colors(cause: np.ndarray) -> np.ndarray:
    """uint8 [M, 3] marker colour per cause code (unknown codes are near-black)."""
    cause = np.asarray(cause).reshape(-1)
    out = np.empty((cause.size, 3), dtype=np.uint8)
    out[:] = UNKNOWN_CAUSE_RGB
    for code, rgb in CAUSE_RGB.items():
        out[cause == code] = rgb
    return out


def heading_markers(
    poses: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """White box on each robot's front half, as in the MJCF robots.

    Args:
      poses: [M, 3] world x, y, yaw.
      radii: [M] robot radii.

    Returns:
      positions [M, 3], wxyzs [M, 4], scales [M, 3] of unit boxes.
    """
    yaw = poses[:, 2]
    fwd = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
    xy = poses[:, :2] + 0.6 * radii[:, None] * fwd
    z = np.full((len(poses), 1), 2 * mjcf.ROBOT_HALF_HEIGHT + 0.005)
    scales = np.stack([0.7 * radii, 0.3 * radii, np.full_like(radii, 0.01)], axis=-1)
    return np.concatenate([xy, z], axis=-1), yaw_to_wxyz(yaw), scales


def trail_segments(history: np.ndarray) -> np.ndarray:
    """Line segments of each agent's recent path.

    Args:
      history: [L, M, 2] world positions, oldest first (L >= 1).

    Returns:
      [M * (L - 1), 2, 3] segments (empty when L < 2), agent-major.
    """
    history = np.asarray(history, dtype=np.float32)
    length, m = history.shape[:2]
    if length < 2:
        return np.zeros((0, 2, 3), np.float32)
    start = history[:-1].transpose(1, 0, 2)  # [M, L-1, 2]
    end = history[1:].transpose(1, 0, 2)
    seg = np.stack([start, end], axis=2)  # [M, L-1, 2, 2]
    z = np.full((*seg.shape[:-1], 1), TRAIL_Z, np.float32)
    return np.concatenate([seg, z], axis=-1).reshape(m * (length - 1), 2, 3)


def attention_bars(
    origin: np.ndarray, targets: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat bars from `origin` [2] to each target [M, 2], width growing with the weight [M].

    Returns positions [M, 3], wxyzs [M, 4], scales [M, 3] of unit boxes; a weight below
    `ATTENTION_MIN_WEIGHT` gets scale 0 (not drawn).
    """
    origin = np.asarray(origin, np.float32)
    targets = np.asarray(targets, np.float32).reshape(-1, 2)
    weights = np.asarray(weights, np.float32).reshape(-1)
    delta = targets - origin[None]
    length = np.linalg.norm(delta, axis=-1)
    yaw = np.arctan2(delta[:, 1], delta[:, 0])
    mid = origin[None] + 0.5 * delta
    positions = np.concatenate([mid, np.full((len(mid), 1), ATTENTION_Z, np.float32)], axis=-1)
    base, slope = ATTENTION_WIDTH
    width = base + slope * weights
    shown = weights >= ATTENTION_MIN_WEIGHT
    scales = np.stack([length, width, np.full_like(width, 0.01)], axis=-1)
    scales = np.where(shown[:, None], scales, 0.0).astype(np.float32)
    return positions.astype(np.float32), yaw_to_wxyz(yaw), scales


def _mesh(kind: str) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    if kind == "cylinder":  # radius 1, height 1, centred
        mesh = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=32)
    elif kind == "box":  # unit cube, centred
        mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    elif kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    else:
        raise ValueError(kind)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32)


def _ring(r_in: float, r_out: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    mesh = trimesh.creation.annulus(r_min=r_in, r_max=r_out, height=height, sections=128)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32)


def _identity(n: int) -> np.ndarray:
    return np.tile(np.asarray([1.0, 0.0, 0.0, 0.0], np.float32), (n, 1))


# ----------------------------------------------------------------------------- the scene


class ArenaScene:
    """The viser handles of B arenas of one config; `update(frame)` moves everything at once."""

    def __init__(
        self,
        server: Any,
        config: EnvConfig,
        num_arenas: int,
        root: str = "/arenas",
    ):
        """Builds every handle (call `remove` before building another scene on the same root).

        Args:
          server: a `viser.ViserServer`.
          config: the scene's env config.
          num_arenas: B, arenas shown side by side.
          root: scene-tree prefix of all handles.
        """
        self.server = server
        self.config = config
        self.num_arenas = num_arenas
        self.root = root
        self.offsets = grid_offsets(num_arenas, config.arena.radius)
        p, e = config.pursuer.num_agents, config.evader.num_agents
        self.num_agents = p + e
        self.team_slices = {"pursuer": slice(0, p), "evader": slice(p, p + e)}
        self.radii = np.asarray(
            [config.pursuer.radius] * p + [config.evader.radius] * e, dtype=np.float32
        )
        self.trails_visible = True
        self._handles: dict[str, Any] = {}
        self._build()

    # -- construction

    def _batched(self, name: str, mesh: tuple[np.ndarray, np.ndarray], n: int, **kw: Any) -> Any:
        vertices, faces = mesh
        kw.setdefault("batched_wxyzs", _identity(n))
        kw.setdefault("batched_positions", np.zeros((n, 3), np.float32))
        kw.setdefault("batched_scales", np.zeros((n, 3), np.float32))
        handle = self.server.scene.add_batched_meshes_simple(
            f"{self.root}/{name}",
            vertices,
            faces,
            lod="off",
            flat_shading=True,
            cast_shadow=False,
            receive_shadow=False,
            **kw,
        )
        self._handles[name] = handle
        return handle

    def _build(self) -> None:
        cfg, b = self.config, self.num_arenas
        radius = cfg.arena.radius
        flat = np.zeros((b, 1), np.float32)
        floor_pos = np.concatenate([self.offsets, flat - 0.01], axis=-1)
        floor_r = radius + mjcf.WALL_THICKNESS + FLOOR_MARGIN
        self._batched(
            "floor",
            _mesh("cylinder"),
            b,
            batched_positions=floor_pos,
            batched_scales=np.tile([floor_r, floor_r, 0.02], (b, 1)).astype(np.float32),
            batched_colors=FLOOR_RGB,
        )
        wall_h = 2 * mjcf.WALL_HALF_HEIGHT
        self._batched(
            "wall",
            _ring(radius, radius + mjcf.WALL_THICKNESS, wall_h),
            b,
            batched_positions=np.concatenate([self.offsets, flat + wall_h / 2], axis=-1),
            batched_scales=np.ones((b, 3), np.float32),
            batched_colors=WALL_RGB,
        )
        k = cfg.arena.num_obstacles
        if k:
            self._batched("obstacles", _mesh("cylinder"), b * k, batched_colors=OBSTACLE_RGB)
        for team in TEAMS:
            n = b * cfg.team(team).num_agents
            self._batched(f"{team}s", _mesh("cylinder"), n, batched_colors=TEAM_RGB[team])
        n_all = b * self.num_agents
        self._batched("headings", _mesh("box"), n_all, batched_colors=MARKER_RGB)
        self._batched("markers", _mesh("sphere"), n_all, batched_colors=UNKNOWN_CAUSE_RGB)
        for team in TEAMS:
            light = tuple(int(c + 0.45 * (255 - c)) for c in TEAM_RGB[team])
            self._handles[f"{team}_trail"] = self.server.scene.add_line_segments(
                f"{self.root}/{team}_trail",
                points=np.zeros((1, 2, 3), np.float32),
                colors=light,
                thickness=0.02,
            )
        m = max(1, self.num_agents - 1 + k)
        self._batched("attention", _mesh("box"), m, visible=False, batched_colors=(0, 0, 0))

    @property
    def handles(self) -> dict[str, Any]:
        """The viser scene handles by kind ("pursuers", "evaders", "obstacles", ...): one batched
        handle per body kind."""
        return dict(self._handles)

    def camera_pose(
        self, aspect: float = 4 / 3, panel: float = 0.3
    ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(position, look_at) of a camera, tilted a little, that fits every arena into the part
        of a browser window of this aspect ratio not covered by the GUI panel on the right."""
        half = self.config.arena.radius + mjcf.WALL_THICKNESS + 0.2
        half_w = float(np.max(np.abs(self.offsets[:, 0]))) + half
        half_h = float(np.max(np.abs(self.offsets[:, 1]))) + half
        tan = math.tan(0.5 * CAMERA_FOV)
        dist = 1.35 * max(half_h, half_w / (aspect * (1 - panel))) / tan
        shift = 0.8 * panel * dist * tan * aspect
        return (shift, -0.15 * dist, dist), (shift, 0.0, 0.0)

    def remove(self) -> None:
        for handle in self._handles.values():
            handle.remove()
        self._handles.clear()

    # -- updates

    def set_trails_visible(self, visible: bool) -> None:
        self.trails_visible = visible
        for team in TEAMS:
            self._handles[f"{team}_trail"].visible = visible

    def update(
        self,
        frame: Frame,
        trail: np.ndarray | None = None,
        attention: AttentionOverlay | None = None,
    ) -> None:
        """Moves every body to `frame` in one atomic update.

        Args:
          frame: the arenas' state.
          trail: [L, B, N, 2] recent positions, oldest first (arena frame), or None.
          attention: the overlay to draw, or None to hide it.
        """
        cfg, b, n = self.config, self.num_arenas, self.num_agents
        poses = np.asarray(frame.poses, np.float32).reshape(b, n, 3)
        world = poses.copy()
        world[..., :2] += self.offsets[:, None, :]
        active = np.asarray(frame.active, bool).reshape(b, n)
        cause = np.asarray(frame.cause).reshape(b, n)
        radii = np.broadcast_to(self.radii, (b, n))
        h = self._handles
        with self.server.atomic():
            k = cfg.arena.num_obstacles
            if k:
                obstacles = np.asarray(frame.obstacles, np.float32).reshape(b, k, 3)
                xy = (obstacles[..., :2] + self.offsets[:, None, :]).reshape(-1, 2)
                r = obstacles[..., 2].reshape(-1)
                h["obstacles"].batched_positions = np.concatenate(
                    [xy, np.full((len(xy), 1), mjcf.WALL_HALF_HEIGHT, np.float32)], axis=-1
                )
                h["obstacles"].batched_scales = np.stack(
                    [r, r, np.full_like(r, 2 * mjcf.WALL_HALF_HEIGHT)], axis=-1
                )
            for team, sl in self.team_slices.items():
                pose = world[:, sl].reshape(-1, 3)
                r = radii[:, sl].reshape(-1)
                handle = h[f"{team}s"]
                z = np.full((len(pose), 1), mjcf.ROBOT_HALF_HEIGHT, np.float32)
                handle.batched_positions = np.concatenate([pose[:, :2], z], axis=-1)
                handle.batched_wxyzs = yaw_to_wxyz(pose[:, 2])
                handle.batched_scales = np.stack(
                    [r, r, np.full_like(r, 2 * mjcf.ROBOT_HALF_HEIGHT)], axis=-1
                )
                handle.batched_colors = robot_colors(TEAM_RGB[team], active[:, sl])
            flat_pose = world.reshape(-1, 3)
            flat_r = radii.reshape(-1)
            pos, wxyz, scale = heading_markers(flat_pose, flat_r)
            h["headings"].batched_positions = pos
            h["headings"].batched_wxyzs = wxyz
            h["headings"].batched_scales = scale
            down = ~active.reshape(-1)
            marker_pos = np.concatenate(
                [flat_pose[:, :2], np.full((len(flat_pose), 1), MARKER_Z, np.float32)], axis=-1
            )
            h["markers"].batched_positions = marker_pos
            h["markers"].batched_scales = np.where(
                down[:, None], 0.6 * flat_r[:, None], 0.0
            ).repeat(3, axis=1)
            h["markers"].batched_colors = cause_colors(cause)
            if trail is not None and self.trails_visible:
                self._update_trails(np.asarray(trail, np.float32))
            self._update_attention(world, attention)

    def _update_trails(self, trail: np.ndarray) -> None:
        b, n = self.num_arenas, self.num_agents
        trail = trail.reshape(trail.shape[0], b, n, 2) + self.offsets[None, :, None, :]
        for team, sl in self.team_slices.items():
            seg = trail_segments(trail[:, :, sl].reshape(trail.shape[0], -1, 2))
            if len(seg) == 0:
                seg = np.zeros((1, 2, 3), np.float32)
            self._handles[f"{team}_trail"].points = seg

    def _update_attention(self, world: np.ndarray, overlay: AttentionOverlay | None) -> None:
        handle = self._handles["attention"]
        if overlay is None:
            handle.visible = False
            return
        offset = self.offsets[overlay.arena]
        origin = world[overlay.arena, overlay.agent, :2]
        targets = np.asarray(overlay.targets, np.float32).reshape(-1, 2) + offset
        pos, wxyz, scale = attention_bars(origin, targets, overlay.weights)
        m = handle.batched_positions.shape[0]
        pad = m - len(pos)
        if pad < 0:
            raise ValueError(f"attention overlay has {len(pos)} entities; the scene holds {m}")
        colors = np.asarray([ATTENTION_RGB[kind] for kind in overlay.kinds], np.uint8)
        colors = colors.reshape(-1, 3)
        handle.batched_positions = np.concatenate([pos, np.zeros((pad, 3), np.float32)])
        handle.batched_wxyzs = np.concatenate([wxyz, _identity(pad)])
        handle.batched_scales = np.concatenate([scale, np.zeros((pad, 3), np.float32)])
        handle.batched_colors = np.concatenate([colors, np.zeros((pad, 3), np.uint8)])
        handle.visible = True


class TrailBuffer:
    """The last `length` positions of every agent of B arenas (for `ArenaScene.update`)."""

    def __init__(self, length: int):
        self.length = max(1, int(length))
        self._points: list[np.ndarray] = []

    def clear(self) -> None:
        self._points.clear()

    def push(self, positions: np.ndarray) -> None:
        """Appends [B, N, 2]."""
        self._points.append(np.asarray(positions, np.float32).copy())
        del self._points[: -self.length]

    def array(self) -> np.ndarray | None:
        """[L, B, N, 2], padded at the old end by repeating the oldest point; None when empty."""
        if not self._points:
            return None
        pts = self._points
        pad = [pts[0]] * (self.length - len(pts))
        return np.stack(pad + pts)


def configure_lighting(server: Any) -> None:
    """Ambient plus a light from above, no environment map: team colours stay saturated (the
    default environment lighting washes them out), and no HDRI is needed offline."""
    server.scene.configure_environment_map(None)
    server.scene.configure_default_lights(False)
    server.scene.add_light_ambient("/lights/ambient", intensity=1.0)
    server.scene.add_light_directional("/lights/sun", intensity=0.8, position=(0.0, 0.0, 10.0))


__all__ = [
    "ArenaScene",
    "AttentionOverlay",
    "Frame",
    "TrailBuffer",
    "attention_bars",
    "cause_colors",
    "configure_lighting",
    "grid_offsets",
    "heading_markers",
    "robot_colors",
    "trail_segments",
    "yaw_to_wxyz",
]
