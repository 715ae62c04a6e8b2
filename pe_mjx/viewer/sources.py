"""A live run as the viewer's frame source (a replay's is `pe_mjx.viewer.replay.ReplaySource`).

Both kinds answer the same questions (`at_end`, `advance`, `frame`, `trail`, `counters`), so the
app's loop steps either without knowing which it holds.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pe_mjx.viewer.live import LiveRun
from pe_mjx.viewer.scene import TrailBuffer


class LiveSource:
    """A `LiveRun` as a frame source, with its trail buffer."""

    kind = "live"

    def __init__(self, run: LiveRun, trail_length: int):
        self.run = run
        self.config = run.config
        self.num_arenas = run.num_arenas
        self.trails = TrailBuffer(trail_length)
        self.trails.push(run.positions())

    @property
    def at_end(self) -> bool:
        return self.run.done

    def advance(self) -> bool:
        self.run.step()
        self.trails.push(self.run.positions())
        return True

    def reset(self, seed: int) -> None:
        self.run.reset(seed)
        self.trails.clear()
        self.trails.push(self.run.positions())

    def frame(self):
        return self.run.frame()

    def trail(self) -> np.ndarray | None:
        return self.trails.array()

    def counters(self) -> list[dict[str, Any]]:
        return self.run.counters()


__all__ = ["LiveSource"]
