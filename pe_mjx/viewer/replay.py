"""Replays of recorded trajectories and shareable recordings (`.viser` files, standalone HTML).

`ReplaySource` steps through a `pe_mjx.trajectory.Trajectory` frame by frame (the viewer's time
slider). `export_recording` plays frames into a private, headless viser server whose scene
serializer records them, and writes

* ``<stem>.viser``: viser's recording format; open it with viser's client page and
  ``?playbackPath=<file>`` (any static web server), and
* ``<stem>.html``: one self-contained page (viser's client with the recording inlined) that plays in
  a browser from disk, with no server.
"""

from __future__ import annotations

import base64
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from pe_mjx import outputs
from pe_mjx.config import get_preset
from pe_mjx.names import TEAMS
from pe_mjx.trajectory import Trajectory
from pe_mjx.viewer.live import LiveRun, arena_counters, load_team_policy
from pe_mjx.viewer.scene import ArenaScene, Frame, TrailBuffer, configure_lighting


class ReplaySource:
    """A trajectory as a frame source with a cursor (frame index)."""

    kind = "replay"

    def __init__(self, traj: Trajectory, trail_length: int = 30):
        self.traj = traj
        self.config = traj.config
        self.num_arenas = traj.num_arenas
        self.trail_length = max(1, trail_length)
        self.index = 0
        self._causes = traj.causes()

    @property
    def num_frames(self) -> int:
        return self.traj.num_frames

    @property
    def at_end(self) -> bool:
        return self.index >= self.num_frames - 1

    def seek(self, index: int) -> None:
        self.index = int(np.clip(index, 0, self.num_frames - 1))

    def advance(self) -> bool:
        """Next frame; False (and no change) at the end."""
        if self.at_end:
            return False
        self.index += 1
        return True

    def frame(self) -> Frame:
        t = self.index
        return Frame(
            poses=self.traj.poses[t],
            active=self.traj.active[t],
            cause=self._causes[t],
            obstacles=self.traj.obstacles,
        )

    def trail(self) -> np.ndarray:
        """[L, B, N, 2] positions up to the cursor, padded with the first frame."""
        t = self.index
        start = t - self.trail_length + 1
        idx = np.clip(np.arange(start, t + 1), 0, None)
        return self.traj.poses[idx, ..., :2]

    def counters(self) -> list[dict[str, Any]]:
        t = self.index
        step = np.full(self.num_arenas, t)
        return arena_counters(self.config, self.traj.active[t], self._causes[t], step)


def html_page(recording: bytes, dark_mode: bool = False) -> str:
    """A self-contained page that plays a `.viser` recording without a server.

    Same as viser's ``StateSerializer.as_html``, which can only serialise once; we need both the
    bytes and the page from one recording.
    """
    import viser

    client = Path(viser.__file__).parent / "client" / "build" / "index.html"
    page = client.read_text()
    data = base64.b64encode(recording).decode("ascii")
    mode = "true" if dark_mode else "false"
    inject = (
        f'<script>window.__VISER_EMBED_DATA__="{data}";'
        f"window.__VISER_EMBED_CONFIG__={{darkMode:{mode}}};</script>"
    )
    head_end = page.index("</head>")
    return page[:head_end] + inject + page[head_end:]


def unique_stem(directory: Path, name: str) -> Path:
    """`directory/name`, or `name-2`, `name-3`, ... so that neither .viser nor .html exists."""
    stem = directory / name
    n = 1
    while stem.with_suffix(".viser").exists() or stem.with_suffix(".html").exists():
        n += 1
        stem = directory / f"{name}-{n}"
    return stem


def write_recording(stem: Path, recording: bytes) -> tuple[Path, Path]:
    """Writes `<stem>.viser` and `<stem>.html` (atomically; never over existing files)."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = (stem.with_suffix(".viser"), stem.with_suffix(".html"))
    for path in paths:
        if path.exists():
            raise FileExistsError(f"{path} exists; refusing to overwrite it")
    payloads: tuple[bytes, bytes] = (recording, html_page(recording).encode("utf-8"))
    for path, payload in zip(paths, payloads, strict=True):
        outputs.write_file(path, payload)  # a temporary beside it, one rename
    return paths


def export_recording(
    config: Any,
    num_arenas: int,
    frames: Iterable[tuple[Frame, np.ndarray | None]],
    stem: str | Path,
    frame_seconds: float,
) -> tuple[Path, Path]:
    """Records frames into `<stem>.viser` and `<stem>.html`.

    Args:
      config: the scene's `EnvConfig`.
      num_arenas: B.
      frames: (frame, trail [L, B, N, 2] or None) in order.
      stem: output path without suffix; refused if either file exists.
      frame_seconds: playback time per frame.
    """
    import viser

    stem = Path(stem)
    for suffix in (".viser", ".html"):
        if stem.with_suffix(suffix).exists():
            raise FileExistsError(f"{stem.with_suffix(suffix)} exists; refusing to overwrite it")
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        configure_lighting(server)
        scene = ArenaScene(server, config, num_arenas)
        position, look_at = scene.camera_pose()
        server.initial_camera.position = position
        server.initial_camera.look_at = look_at
        serializer = server.get_scene_serializer()
        for i, (frame, trail) in enumerate(frames):
            if i:
                serializer.insert_sleep(frame_seconds)
            scene.update(frame, trail)
        serializer.insert_sleep(frame_seconds)
        recording = serializer.serialize()
    finally:
        server.stop()
    return write_recording(stem, recording)


def export_trajectory(
    traj: Trajectory, stem: str | Path, speed: float = 1.0, trail_length: int = 30
) -> tuple[Path, Path]:
    """A whole trajectory as `<stem>.viser` and `<stem>.html`, at `speed` x real time."""
    source = ReplaySource(traj, trail_length)

    def frames():
        for t in range(traj.num_frames):
            source.seek(t)
            yield source.frame(), source.trail()

    dt = traj.config.control_dt / max(speed, 1e-6)
    return export_recording(traj.config, traj.num_arenas, frames(), stem, dt)


def timestamp() -> str:
    return time.strftime("%Y%m%d-%H%M%S")


def export_live(
    preset: str,
    pursuers: str,
    evaders: str,
    arenas: int,
    backend: str,
    seed: int,
    steps: int,
    stem: str | Path,
    speed: float = 1.0,
    trail_length: int = 30,
) -> tuple[Path, Path]:
    """Plays `steps` live control steps headless and writes them as `<stem>.viser` / `.html`.

    Raises PolicyError (a ValueError) when a policy does not fit; nothing is written then.
    """
    config = get_preset(preset)
    specs = {"pursuer": pursuers, "evader": evaders}
    policies = {t: load_team_policy(specs[t], config, t) for t in TEAMS}
    run = LiveRun(config, policies, arenas, backend, seed)
    trails = TrailBuffer(trail_length)

    def frames():
        for i in range(steps + 1):
            if i:
                if run.done:
                    break
                run.step()
            trails.push(run.positions())
            yield run.frame(), trails.array()

    dt = config.control_dt / max(speed, 1e-6)
    return export_recording(config, arenas, frames(), stem, dt)


__all__ = [
    "ReplaySource",
    "export_live",
    "export_recording",
    "export_trajectory",
    "html_page",
    "unique_stem",
    "write_recording",
]
