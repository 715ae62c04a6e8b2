"""The viewer's web app: viser server, GUI, and the loop thread that steps and streams the arenas.

Threads: viser runs GUI callbacks on its own pool; they only post commands to a queue. One loop
thread owns the frame source (a live run, a replay, or the training view's run) and the scene: it
runs the queued commands, advances the source at the chosen speed and pushes each frame to every
browser inside one ``server.atomic()`` block. An error in a command (a bad checkpoint path, a
scene that cannot be placed) is shown in the GUI and printed on stderr; the loop keeps going.
Browser tabs come and go (viser replays the scene to a new tab); the server never stops for them.

A browser is not trusted: `pe_mjx.viewer.guard` checks every GUI value it sends (type, finite,
bounds, options) before viser applies it, refuses and shows anything else, and limits the policy
paths typed into the page to run directories under a few roots.
"""

from __future__ import annotations

import contextlib
import dataclasses
import queue
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pe_mjx.config import get_preset
from pe_mjx.names import BACKENDS
from pe_mjx.policy.scripted import POLICIES
from pe_mjx.trajectory import Trajectory
from pe_mjx.viewer.commands import SceneCommands
from pe_mjx.viewer.guard import MAX_ARENAS, SEED_MAX, GuiGuard, PolicyAccess, check_address
from pe_mjx.viewer.gui import build_controls, counters_markdown
from pe_mjx.viewer.options import ViewerOptions
from pe_mjx.viewer.recording import RecordingCommands
from pe_mjx.viewer.replay import ReplaySource
from pe_mjx.viewer.scene import ArenaScene, configure_lighting
from pe_mjx.viewer.sources import LiveSource
from pe_mjx.viewer.training_view import TrainingView

COUNTER_PERIOD = 0.25
"""Seconds between counter-table refreshes."""
MAX_ERRORS = 1000
"""Error messages kept in `Viewer.errors` (a hostile client may send many bad values)."""


class Viewer(SceneCommands, RecordingCommands, TrainingView):
    """The running app. Build it with `start_viewer`; stop it with `stop()`.

    Its loop-thread commands live in mixins by role (`commands.SceneCommands`: playback, scene,
    policies, attention; `recording.RecordingCommands`; `training_view.TrainingView`), so that
    this class keeps the threads, the public surface, the GUI wiring and the loop; a caller
    still sees one class with every method it had."""

    def __init__(
        self,
        options: ViewerOptions,
        replay: Trajectory | None = None,
        training: bool = False,
        policies: dict[str, Any] | None = None,
    ):
        import viser

        if options.arenas is None:  # a live run's default (a replay's arenas are its own)
            options = dataclasses.replace(options, arenas=1)
        if replay is None and not training:
            get_preset(options.preset)  # fail early, with the list of presets
        if options.backend not in BACKENDS:
            raise ValueError(f"unknown backend {options.backend!r}; expected one of {BACKENDS}")
        if not 1 <= options.arenas <= MAX_ARENAS:
            raise ValueError(f"arenas must be in 1..{MAX_ARENAS}, got {options.arenas}")
        if not 0 <= options.seed <= SEED_MAX:
            raise ValueError(f"seed must be in 0..{SEED_MAX}, got {options.seed}")
        if not check_address(options.host, options.port):
            print(
                f"pe-mjx view: warning: --host {options.host} serves the viewer to other "
                "machines; anyone who can reach it can control it (there is no login)",
                file=sys.stderr,
                flush=True,
            )
        self.options = options
        # Policies the caller already resolved for options.pursuers/evaders (`pe-mjx view`):
        # the first live run plays them instead of restoring each checkpoint again.
        self._resolved = policies
        access = PolicyAccess.default(options.policy_roots)
        self.policy_access = access.allowing(
            *(p for p in (options.pursuers, options.evaders) if p.strip() not in ("", *POLICIES))
        )
        self.mode = "replay" if replay is not None else ("training" if training else "live")
        self.server = viser.ViserServer(
            host=options.host, port=options.port, label="pe-mjx", verbose=False
        )
        self.guard = GuiGuard(self.server, self._reject)
        configure_lighting(self.server)
        self.source: LiveSource | ReplaySource | None = None
        self.scene: ArenaScene | None = None
        self.playing = options.play
        self.speed = options.speed
        self.loop_episodes = options.loop
        self.frames_streamed = 0
        self.errors: list[str] = []
        self.recordings: list[Path] = []
        self._serializer: Any = None
        self._commands: queue.Queue[Callable[[], None]] = queue.Queue()
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._step_once = False
        self._hold_until: float | None = None
        self._last_counters = 0.0
        self._last_frame_time: float | None = None
        self._training_started = False
        self.gui = build_controls(self.server, self.guard, options, self.mode)
        self._wire_gui()
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        if replay is not None:
            self.post(lambda: self._set_source(ReplaySource(replay, options.trail_length)))
        elif not training:
            self.post(self._start_live)
        self._thread = threading.Thread(target=self._loop, name="pe-mjx-viewer", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ public surface

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    @property
    def port(self) -> int:
        return self.server.get_port()

    def post(self, command: Callable[[], None]) -> None:
        """Runs `command` on the loop thread (the only thread that touches source and scene)."""
        self._commands.put(command)

    def call(self, command: Callable[[], Any], timeout: float = 300.0) -> Any:
        """Runs `command` on the loop thread and returns its result (for tests and scripts)."""
        done = threading.Event()
        box: dict[str, Any] = {}

        def run() -> None:
            try:
                box["value"] = command()
            except Exception as err:
                box["error"] = err
            finally:
                done.set()

        self.post(run)
        if not done.wait(timeout):
            raise TimeoutError(f"viewer command did not finish within {timeout} s")
        if "error" in box:
            raise box["error"]
        return box.get("value")

    def wait_ready(self, timeout: float = 600.0) -> None:
        """Blocks until the first frame is on the server (or raises the startup error)."""
        if not self._ready.wait(timeout):
            raise TimeoutError(f"the viewer did not show a frame within {timeout} s")
        if self.source is None and self.mode != "training":
            raise RuntimeError("the viewer failed to start: " + "; ".join(self.errors))

    def stop(self) -> None:
        """Stops the loop and the server. The loop thread is a daemon: one busy in a long command
        (building a large scene) is left to end with the process after a short wait."""
        self._stop.set()
        self._thread.join(timeout=5)
        self.server.stop()

    def num_clients(self) -> int:
        return len(self.server.get_clients())

    # Control from any thread, as the GUI buttons do; each returns once the loop has done it.

    def play(self) -> None:
        """Plays (live arenas step, a replay advances) at the set speed."""
        self.call(lambda: self._set_playing(True))

    def pause(self) -> None:
        self.call(lambda: self._set_playing(False))

    def step(self) -> None:
        """Pauses and advances exactly one control step (one frame of a replay)."""
        self.call(self._request_step)

    def seek(self, index: int) -> None:
        """Shows frame `index` of a replay (nothing for live arenas)."""
        self.call(lambda: self._seek(index))

    def reset(self, seed: int) -> None:
        """New live arenas drawn from `seed`; a replay goes back to its first frame."""
        self.call(lambda: self._reset(seed))

    @property
    def recording(self) -> bool:
        """Whether a recording (Start recording) is in progress."""
        return self._serializer is not None

    @property
    def running(self) -> bool:
        """Whether the loop thread is alive."""
        return self._thread.is_alive()

    # ------------------------------------------------------------------ errors and status

    def _report(self, message: str, notify: bool = True) -> None:
        self.errors.append(message)
        del self.errors[:-MAX_ERRORS]
        print(f"pe-mjx view: error: {message}", file=sys.stderr, flush=True)
        self.gui.error.content = f"**Error:** {message}"
        self.gui.error.visible = True
        if not notify:
            return
        for client in self.server.get_clients().values():
            with contextlib.suppress(Exception):
                client.add_notification(
                    "pe-mjx error", message, color="red", auto_close_seconds=15.0
                )

    def _reject(self, message: str) -> None:
        """A GUI value refused by the guard (viser's event loop): shown, never applied. No
        notification pop-ups: a flood of forged messages must not flood every page."""
        self._report(message, notify=False)

    def _clear_error(self) -> None:
        self.gui.error.visible = False

    def _status(self, text: str) -> None:
        self.gui.status.content = text
        if self.options.verbose:
            print(f"pe-mjx view: {text}", flush=True)

    # ------------------------------------------------------------------ GUI

    def _wire_gui(self) -> None:
        """What each control does: most post a command to the loop thread."""

        @self.gui.play.on_click
        def _(_: Any) -> None:
            self.post(lambda: self._set_playing(True))

        @self.gui.pause.on_click
        def _(_: Any) -> None:
            self.post(lambda: self._set_playing(False))

        @self.gui.step.on_click
        def _(_: Any) -> None:
            self.post(self._request_step)

        @self.gui.speed.on_update
        def _(_: Any) -> None:
            self.post(self._read_speed)

        @self.gui.max_speed.on_update
        def _(_: Any) -> None:
            self.post(self._read_speed)

        @self.gui.trails.on_update
        def _(_: Any) -> None:
            self.post(self._apply_trails)

        @self.gui.loop.on_update
        def _(_: Any) -> None:
            self.loop_episodes = bool(self.gui.loop.value)

        @self.gui.frame.on_update
        def _(event: Any) -> None:
            if event.client is not None:  # our own slider moves during playback come with None
                value = int(self.gui.frame.value)
                self.post(lambda: self._seek(value))

        @self.gui.preset.on_update
        def _(_: Any) -> None:
            cfg = get_preset(self.gui.preset.value)
            self.gui.pursuers.value = cfg.pursuer.num_agents
            self.gui.evaders.value = cfg.evader.num_agents
            self.gui.obstacles.value = cfg.arena.num_obstacles

        @self.gui.reset.on_click
        def _(_: Any) -> None:
            seed = int(self.gui.seed.value)
            self.post(lambda: self._reset(seed))

        @self.gui.apply.on_click
        def _(_: Any) -> None:
            self.post(self._apply_scene)

        @self.gui.load.on_click
        def _(_: Any) -> None:
            self.post(self._load_policies)

        for handle in (
            self.gui.att_show,
            self.gui.att_team,
            self.gui.att_arena,
            self.gui.att_agent,
        ):
            handle.on_update(lambda _: self.post(self._push_frame_if_paused))

        @self.gui.record.on_click
        def _(_: Any) -> None:
            self.post(self._toggle_recording)

        @self.gui.export.on_click
        def _(_: Any) -> None:
            self.post(self._export_replay)

    def _on_connect(self, client: Any) -> None:
        if self.scene is not None:
            position, look_at = self.scene.camera_pose()
            client.camera.position = position
            client.camera.look_at = look_at
        if self.options.verbose:
            print(f"pe-mjx view: client {client.client_id} connected ({self.num_clients()} open)")

    def _on_disconnect(self, client: Any) -> None:
        if self.options.verbose:
            print(f"pe-mjx view: client {client.client_id} left ({self.num_clients()} open)")

    # ------------------------------------------------------------------ the loop

    def _push_frame_if_paused(self) -> None:
        if not self.playing:
            self._push_frame()

    def _push_frame(self, source: LiveSource | ReplaySource | None = None) -> None:
        """Sends the frame of `source` (a new one, before `_set_source` publishes it; else the
        current source): scene, replay slider and, at most every COUNTER_PERIOD while playing,
        the counters (always for a new source)."""
        first = source is not None
        source = self.source if source is None else source
        if source is None or self.scene is None:
            return
        trail = source.trail() if self.gui.trails.value else None
        if self._serializer is not None:
            now = time.monotonic()
            self._serializer.insert_sleep(max(now - self._last_record_time, 0.0))
            self._last_record_time = now
        self.scene.update(source.frame(), trail, self._attention(source))
        self.frames_streamed += 1
        if isinstance(source, ReplaySource):
            self.gui.frame.value = source.index
        now = time.monotonic()
        if first or now - self._last_counters >= COUNTER_PERIOD or not self.playing:
            self._last_counters = now
            label = "frame t" if isinstance(source, ReplaySource) else "t"
            self.gui.counters.content = counters_markdown(source.counters(), source.config, label)

    def _advance(self) -> None:
        """One step of the source, with episode looping."""
        source = self.source
        assert source is not None
        if source.at_end:
            if not self.loop_episodes and not self._step_once:
                return
            now = time.monotonic()
            if self._hold_until is None and not self._step_once:
                self._hold_until = now + self.options.hold
                return
            if self._hold_until is not None and now < self._hold_until and not self._step_once:
                return
            self._hold_until = None
            if isinstance(source, ReplaySource):
                source.seek(0)
            else:
                source.reset((source.run.seed + 1) % (SEED_MAX + 1))
                self.gui.seed.value = source.run.seed
                self._status(self._live_status())
        else:
            source.advance()
        self._push_frame()

    def _run_command(self, command: Callable[[], None]) -> bool:
        """Runs one command; an error is reported (GUI and stderr) and False returned."""
        try:
            command()
            return True
        except Exception as err:  # never let a command kill the loop
            message = str(err) or type(err).__name__
            if not isinstance(err, ValueError | FileExistsError | OSError):
                traceback.print_exc()
                message = f"{type(err).__name__}: {message}"
            self._report(message)
            if self.source is not None and self.mode == "live" and self.source.kind == "live":
                self._status(self._live_status())
            return False
        finally:
            if self.source is None and self.mode != "training" and self.errors:
                self._status("**failed to start** (see the error)")
                self._ready.set()  # startup failed; wait_ready raises

    def _loop(self) -> None:
        next_time = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            wait = 0.05
            if self.source is not None and self.playing and self.speed > 0:
                wait = max(0.0, min(wait, next_time - now))
            elif self.source is not None and (self.playing or self._step_once):
                wait = 0.0
            try:
                command = (
                    self._commands.get(timeout=wait) if wait > 0 else self._commands.get_nowait()
                )
            except queue.Empty:
                command = None
            if command is not None:
                self._run_command(command)
                continue
            if self.source is None or not (self.playing or self._step_once):
                continue
            now = time.monotonic()
            if self.playing and self.speed > 0:
                if now < next_time:
                    continue
                next_time = max(next_time + 1.0 / self.speed, now)
            if not self._run_command(self._advance):
                self.playing = False  # one report, not one per frame
            self._step_once = False


def start_viewer(
    options: ViewerOptions | None = None,
    replay: Trajectory | None = None,
    training: bool = False,
    wait: bool = True,
    policies: dict[str, Any] | None = None,
    **overrides: Any,
) -> Viewer:
    """Starts the viewer (server, GUI, loop thread) and, with `wait`, blocks until the first frame.

    Args:
      options: the starting options; keyword `overrides` replace fields of it
        (``start_viewer(preset="4-1-2", port=0, backend="kinematic")``).
      replay: a trajectory to replay instead of a live run.
      training: an empty viewer fed by `Viewer.training_update` (``pe-mjx train --view``).
      wait: block until the first frame has been sent (not for `training`).
      policies: team -> `Policy` already resolved for the options' `pursuers`/`evaders` (and
        `deterministic`), played by the first live run instead of being loaded again.
    """
    options = dataclasses.replace(options or ViewerOptions(), **overrides)
    viewer = Viewer(options, replay=replay, training=training, policies=policies)
    if wait and not training:
        try:
            viewer.wait_ready()
        except BaseException:
            viewer.stop()
            raise
    return viewer


__all__ = ["Viewer", "ViewerOptions", "start_viewer"]
