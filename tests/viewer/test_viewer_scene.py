"""Config and state to viser: the numpy helpers, and the handles of a real (headless) server."""

from __future__ import annotations

import math

import numpy as np
import pytest
import viser

from pe_mjx import scene as mjcf
from pe_mjx.config import get_preset
from pe_mjx.names import CAPTURE, WALL
from pe_mjx.viewer.scene import (
    ATTENTION_MIN_WEIGHT,
    CAUSE_RGB,
    INACTIVE_RGB,
    TEAM_RGB,
    ArenaScene,
    AttentionOverlay,
    Frame,
    TrailBuffer,
    attention_bars,
    cause_colors,
    grid_offsets,
    heading_markers,
    robot_colors,
    trail_segments,
    yaw_to_wxyz,
)
from tests.viewer.viewer_helpers import synthetic_trajectory


def test_grid_offsets_are_centred_and_do_not_overlap():
    assert np.allclose(grid_offsets(1, 5.0), 0.0)
    for b in (2, 3, 4, 5, 9):
        offsets = grid_offsets(b, 5.0)
        assert offsets.shape == (b, 2)
        if b in (2, 4, 9):  # full grids are centred on the origin
            np.testing.assert_allclose(offsets.mean(axis=0), 0.0, atol=1e-4)
        d = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1)
        d[np.eye(b, dtype=bool)] = np.inf
        assert d.min() >= 2 * (5.0 + mjcf.WALL_THICKNESS)


def test_yaw_to_wxyz_rotates_x_to_heading():
    yaw = np.asarray([0.0, math.pi / 2, -2.0])
    q = yaw_to_wxyz(yaw)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-6)
    w, z = q[:, 0], q[:, 3]
    # Rotation of (1, 0, 0) about z by the quaternion: (cos 2t, sin 2t) with w = cos t, z = sin t.
    x_axis = np.stack([w**2 - z**2, 2 * w * z], axis=-1)
    np.testing.assert_allclose(x_axis, np.stack([np.cos(yaw), np.sin(yaw)], -1), atol=1e-6)


def test_colours_follow_activity_and_cause():
    colors = robot_colors(TEAM_RGB["pursuer"], np.asarray([True, False]))
    assert tuple(colors[0]) == TEAM_RGB["pursuer"] and tuple(colors[1]) == INACTIVE_RGB
    marks = cause_colors(np.asarray([WALL, CAPTURE, -1]))
    assert tuple(marks[0]) == CAUSE_RGB[WALL] and tuple(marks[1]) == CAUSE_RGB[CAPTURE]
    assert TEAM_RGB["pursuer"] != TEAM_RGB["evader"]


def test_heading_markers_sit_in_front():
    poses = np.asarray([[1.0, 2.0, math.pi / 2]], np.float32)
    pos, _, scale = heading_markers(poses, np.asarray([0.1], np.float32))
    np.testing.assert_allclose(pos[0, :2], [1.0, 2.06], atol=1e-6)
    np.testing.assert_allclose(scale[0], [0.07, 0.03, 0.01], atol=1e-6)


def test_trail_segments_connect_consecutive_points():
    history = np.zeros((3, 2, 2), np.float32)  # L=3 points of M=2 agents
    history[:, 0, 0] = [0.0, 1.0, 2.0]
    history[:, 1, 1] = [5.0, 6.0, 7.0]
    seg = trail_segments(history)
    assert seg.shape == (4, 2, 3)
    np.testing.assert_allclose(seg[0, :, :2], [[0, 0], [1, 0]])
    np.testing.assert_allclose(seg[1, :, :2], [[1, 0], [2, 0]])
    np.testing.assert_allclose(seg[3, :, :2], [[0, 6], [0, 7]])
    assert trail_segments(history[:1]).shape == (0, 2, 3)


def test_trail_buffer_pads_with_the_oldest_point():
    buf = TrailBuffer(4)
    assert buf.array() is None
    for k in range(6):
        buf.push(np.full((1, 2, 2), k, np.float32))
    arr = buf.array()
    assert arr.shape == (4, 1, 2, 2) and arr[0, 0, 0, 0] == 2 and arr[-1, 0, 0, 0] == 5
    buf.clear()
    buf.push(np.zeros((1, 2, 2)))
    assert buf.array().shape == (4, 1, 2, 2)


def test_attention_bars_width_grows_with_weight_and_small_ones_hidden():
    origin = np.asarray([0.0, 0.0])
    targets = np.asarray([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    weights = np.asarray([0.6, 0.3, ATTENTION_MIN_WEIGHT / 2])
    pos, wxyz, scale = attention_bars(origin, targets, weights)
    np.testing.assert_allclose(pos[:2, :2], [[0.5, 0.0], [0.0, 1.0]], atol=1e-6)
    np.testing.assert_allclose(scale[:2, 0], [1.0, 2.0], atol=1e-6)  # length
    assert scale[0, 1] > scale[1, 1] > 0  # width
    assert np.all(scale[2] == 0)  # not drawn
    np.testing.assert_allclose(wxyz[1], yaw_to_wxyz(np.asarray(math.pi / 2)), atol=1e-6)


@pytest.fixture(scope="module")
def server():
    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield s
    s.stop()


def test_arena_scene_handles_follow_the_frame(server):
    traj = synthetic_trajectory(frames=40, arenas=2)
    config = get_preset("4-1-2")
    scene = ArenaScene(server, config, num_arenas=2)
    try:
        handles = scene.handles
        assert handles["pursuers"].batched_positions.shape == (2 * 4, 3)
        assert handles["evaders"].batched_positions.shape == (2 * 1, 3)
        assert handles["obstacles"].batched_positions.shape == (2 * 2, 3)
        assert handles["headings"].batched_positions.shape == (2 * 5, 3)
        t = 35  # after the capture in arena 0 and the wall hit in arena 1
        frame = Frame(traj.poses[t], traj.active[t], traj.cause[t], traj.obstacles)
        trail = traj.poses[t - 4 : t + 1, ..., :2]
        overlay = AttentionOverlay(
            arena=1,
            agent=0,
            targets=np.concatenate([traj.poses[t, 1, 1:, :2], traj.obstacles[1, :, :2]]),
            weights=np.asarray([0.1, 0.2, 0.1, 0.3, 0.1, 0.1]),
            kinds=("teammates",) * 3 + ("opponents",) + ("obstacles",) * 2,
        )
        scene.update(frame, trail, overlay)
        offsets = scene.offsets
        pursuers = handles["pursuers"].batched_positions.reshape(2, 4, 3)
        np.testing.assert_allclose(
            pursuers[..., :2], traj.poses[t, :, :4, :2] + offsets[:, None], atol=1e-5
        )
        colors = handles["pursuers"].batched_colors.reshape(2, 4, 3)
        assert tuple(colors[0, 0]) == INACTIVE_RGB and tuple(colors[0, 1]) == TEAM_RGB["pursuer"]
        assert tuple(colors[1, 1]) == INACTIVE_RGB
        marker_scale = handles["markers"].batched_scales.reshape(2, 5, 3)
        assert marker_scale[0, 0, 0] > 0 and marker_scale[0, 1, 0] == 0
        marker_colors = handles["markers"].batched_colors.reshape(2, 5, 3)
        assert tuple(marker_colors[0, 4]) == CAUSE_RGB[CAPTURE]
        assert tuple(marker_colors[1, 1]) == CAUSE_RGB[WALL]
        obstacles = handles["obstacles"].batched_scales.reshape(2, 2, 3)
        np.testing.assert_allclose(obstacles[..., 0], traj.obstacles[..., 2])
        assert handles["pursuer_trail"].points.shape == (2 * 4 * 4, 2, 3)
        assert handles["attention"].visible
        scene.set_trails_visible(False)
        assert not handles["pursuer_trail"].visible
        scene.update(frame)
        assert not handles["attention"].visible
        position, look_at = scene.camera_pose()
        assert position[2] > 0 and look_at[2] == 0
    finally:
        scene.remove()
