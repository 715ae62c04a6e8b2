"""Helpers of the viewer tests: polling, what a screenshot shows, a hand-made trajectory."""

from __future__ import annotations

import math
import time

import numpy as np

from pe_mjx.config import get_preset
from pe_mjx.env import CAPTURE, WALL
from pe_mjx.trajectory import Trajectory
from pe_mjx.viewer.browser import scene_region, team_pixels

LIVE_PRESET = "4-1-2"


def wait_until(predicate, timeout: float = 60.0, interval: float = 0.1, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


def team_counts(image: np.ndarray) -> dict[str, int]:
    return {team: int(mask.sum()) for team, mask in team_pixels(scene_region(image)).items()}


def shows_both_teams(image: np.ndarray, minimum: int = 20) -> bool:
    counts = team_counts(image)
    return counts["pursuer"] >= minimum and counts["evader"] >= minimum


def robots_mask(image: np.ndarray) -> np.ndarray:
    masks = team_pixels(scene_region(image))
    return masks["pursuer"] | masks["evader"]


def synthetic_trajectory(frames: int = 40, arenas: int = 2) -> Trajectory:
    """A hand-made trajectory of the 4-1-2 preset: agents on circles, one captured pair and
    one wall collision late in the episode (no env, no compile)."""
    config = get_preset(LIVE_PRESET)
    n = config.num_agents
    t = np.arange(frames)[:, None, None]
    b = np.arange(arenas)[None, :, None]
    i = np.arange(n)[None, None, :]
    phase = 2 * math.pi * i / n + 0.3 * b
    radius = 0.8 + 0.25 * (i % 3)
    angle = phase + 0.05 * t
    poses = np.stack(
        [radius * np.cos(angle), radius * np.sin(angle), angle + math.pi / 2], axis=-1
    ).astype(np.float32)
    active = np.ones((frames, arenas, n), bool)
    cause = np.zeros((frames, arenas, n), np.int32)
    late = frames * 3 // 4
    active[late:, 0, [0, 4]] = False  # pursuer 0 captured the evader in arena 0
    cause[late:, 0, [0, 4]] = CAPTURE
    active[late:, 1, 1] = False
    cause[late:, 1, 1] = WALL
    poses[late:, 0, [0, 4]] = poses[late, 0, [0, 4]]  # the downed stay where they fell
    poses[late:, 1, 1] = poses[late, 1, 1]
    obstacles = np.tile(
        np.asarray([[1.6, 0.0, 0.35], [-1.5, -0.6, 0.3]], np.float32), (arenas, 1, 1)
    )
    return Trajectory(
        config=config,
        poses=poses,
        active=active,
        obstacles=obstacles,
        cause=cause,
        meta={"source": "synthetic"},
    )
