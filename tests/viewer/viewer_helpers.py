"""Helpers of the viewer tests: polling, what a screenshot shows, a hand-made trajectory, and a
websocket client that forges what a browser could send."""

from __future__ import annotations

import math
import time

import numpy as np

from pe_mjx.config import get_preset
from pe_mjx.names import CAPTURE, WALL
from pe_mjx.trajectory import Trajectory
from tests.viewer.browser import LIVE_VIEWER, scene_region, team_pixels

LIVE_PRESET = LIVE_VIEWER["preset"]


def wait_until(predicate, timeout: float = 60.0, interval: float = 0.1, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


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


class ForgedClient:
    """A websocket client that speaks viser's protocol as its browser client does (one msgpack
    message per frame, the ``viser-v<version>`` subprotocol) to send what no honest page would."""

    def __init__(self, port: int):
        import viser
        from websockets.sync.client import connect

        self.ws = connect(
            f"ws://127.0.0.1:{port}",
            subprotocols=[f"viser-v{viser.__version__}"],
            max_size=None,
            open_timeout=30,
        )
        # A page counts as connected (its clicks reach the callbacks) after its first camera.
        self.send(
            {
                "type": "ViewerCameraMessage",
                "wxyz": (1.0, 0.0, 0.0, 0.0),
                "position": (0.0, 0.0, 5.0),
                "fov": 1.0,
                "near": 0.01,
                "far": 100.0,
                "image_height": 768,
                "image_width": 1024,
                "look_at": (0.0, 0.0, 0.0),
                "up_direction": (0.0, 0.0, 1.0),
            }
        )

    def send(self, message: dict) -> None:
        import msgspec

        self.ws.send(msgspec.msgpack.encode(message))

    def update(self, uuid: str, updates: object) -> None:
        """What the page sends when an input changes (``{"value": ...}`` for a click or value)."""
        self.send({"type": "GuiUpdateMessage", "uuid": uuid, "updates": updates})

    def receive(self, seconds: float) -> int:
        """Messages received in `seconds`; raises if the server closes the connection."""
        from websockets.exceptions import ConnectionClosed

        count, deadline = 0, time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            try:
                self.ws.recv(timeout=left)
            except TimeoutError:
                break
            except ConnectionClosed as err:
                raise AssertionError(f"the server closed the connection: {err}") from None
            count += 1
        return count

    def close(self) -> None:
        self.ws.close()

    def __enter__(self) -> ForgedClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def gui_uuid(handle) -> str:
    """The id a page uses for a GUI element (viser sends it to every page)."""
    return handle._impl.uuid
