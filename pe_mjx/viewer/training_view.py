"""The viewer as `pe-mjx train --view` uses it: the latest policies of a training run, playing.

Split out of `pe_mjx.viewer.app` by role: `TrainingView` is a mixin of `app.Viewer`.
`training_update` is the one method called from another thread (the trainer's); it only posts
commands, which the viewer's loop thread runs like every other command.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pe_mjx.policy.core import Policy
from pe_mjx.viewer.live import LiveRun
from pe_mjx.viewer.sources import LiveSource


class TrainingView:
    """The training view of `app.Viewer` (see the module docstring)."""

    gui: Any
    options: Any
    source: Any
    _training_started: bool
    post: Callable[[Callable[[], None]], None]

    def training_update(self, snapshot: Any) -> None:
        """`train(on_iteration=...)` callback: show the latest policies of a training run.

        `snapshot` is a `pe_mjx.ppo.run.Snapshot` (host copies, taken by the trainer's loop); the
        loop thread builds the live run from the first one and swaps in the learned variables of
        the later ones (no recompilation).
        """
        info = {"iteration": snapshot.iteration, "env_steps": snapshot.env_steps}
        info.update(snapshot.metrics)
        if not self._training_started:
            self._training_started = True
            self.post(lambda: self._start_training(snapshot))
        else:
            self.post(lambda: self._update_training(snapshot.policies))
        self.post(lambda: self._show_training(info))

    def _start_training(self, snapshot: Any) -> None:
        config = snapshot.env_config
        self._status(f"compiling `{config.name}` ({snapshot.backend})...")
        run = LiveRun(
            config, snapshot.policies, self.options.arenas, snapshot.backend, self.options.seed
        )
        self._set_source(LiveSource(run, self.options.trail_length))

    def _update_training(self, policies: dict[str, Policy]) -> None:
        if isinstance(self.source, LiveSource):
            for team, policy in policies.items():
                if policy.learned:
                    self.source.run.set_params(team, policy.variables)

    def _show_training(self, info: dict[str, Any]) -> None:
        lines = [f"**training** iteration {info['iteration']}, {info['env_steps']:,} env steps"]
        for key in sorted(info):
            if key.startswith(("eval/", "perf/env_steps")) and np.isfinite(info[key]):
                lines.append(f"- `{key}`: {info[key]:.3g}")
        self.gui.training.content = "\n".join(lines)


__all__ = ["TrainingView"]
