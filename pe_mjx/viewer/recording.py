"""The viewer's Record folder: a recording of what the page shows, and a replay's export.

Split out of `pe_mjx.viewer.app` by role: `RecordingCommands` is a mixin of `app.Viewer`, run on
its loop thread like the other commands. A recording is viser's scene serializer, fed a sleep
before each pushed frame (`Viewer._push_frame`), so that it plays back at the pace it was shown.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from pe_mjx.viewer.replay import (
    ReplaySource,
    export_trajectory,
    timestamp,
    unique_stem,
    write_recording,
)


class RecordingCommands:
    """Start/stop recording and Export replay of `app.Viewer` (see the module docstring)."""

    gui: Any
    server: Any
    options: Any
    source: Any
    speed: float
    recordings: list[Path]
    _serializer: Any
    _last_record_time: float

    def _toggle_recording(self) -> None:
        if self._serializer is None:
            self._serializer = self.server.get_scene_serializer()
            self._last_record_time = time.monotonic()
            self.gui.record.label = "Stop recording"
            self.gui.record_info.content = "recording..."
            return
        serializer, self._serializer = self._serializer, None
        self.gui.record.label = "Start recording"
        serializer.insert_sleep(max(time.monotonic() - self._last_record_time, 0.0))
        data = serializer.serialize()
        stem = unique_stem(Path(self.options.record_dir), f"pe-mjx-{timestamp()}")
        paths = write_recording(stem, data)
        self._saved(paths)

    def _export_replay(self) -> None:
        if not isinstance(self.source, ReplaySource):
            return
        self.gui.record_info.content = "exporting..."
        stem = unique_stem(Path(self.options.record_dir), f"pe-mjx-replay-{timestamp()}")
        speed = self.speed / (1.0 / self.source.config.control_dt) if self.speed > 0 else 4.0
        paths = export_trajectory(self.source.traj, stem, speed, self.options.trail_length)
        self._saved(paths)

    def _saved(self, paths: tuple[Path, Path]) -> None:
        self.recordings.extend(paths)
        text = " and ".join(f"`{p}`" for p in paths)
        self.gui.record_info.content = f"saved {text}"
        if self.options.verbose:
            print(f"pe-mjx view: saved {paths[0]} and {paths[1]}", flush=True)
        for client in self.server.get_clients().values():
            client.add_notification("Recording saved", text, auto_close_seconds=10.0)


__all__ = ["RecordingCommands"]
