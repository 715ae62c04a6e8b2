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

import numpy as np

from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.names import BACKENDS, TEAMS
from pe_mjx.policy.core import Policy
from pe_mjx.policy.scripted import POLICIES
from pe_mjx.trajectory import Trajectory
from pe_mjx.viewer.guard import (
    MAX_ARENAS,
    SEED_MAX,
    GuiGuard,
    PolicyAccess,
    check_address,
)
from pe_mjx.viewer.gui import build_controls, counters_markdown
from pe_mjx.viewer.live import LiveRun, PolicyError, load_team_policy
from pe_mjx.viewer.options import ViewerOptions
from pe_mjx.viewer.replay import (
    ReplaySource,
    export_trajectory,
    timestamp,
    unique_stem,
    write_recording,
)
from pe_mjx.viewer.scene import (
    ArenaScene,
    TrailBuffer,
    configure_lighting,
)

COUNTER_PERIOD = 0.25
"""Seconds between counter-table refreshes."""
MAX_ERRORS = 1000
"""Error messages kept in `Viewer.errors` (a hostile client may send many bad values)."""


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


class Viewer:
    """The running app. Build it with `start_viewer`; stop it with `stop()`."""

    def __init__(
        self,
        options: ViewerOptions,
        replay: Trajectory | None = None,
        training: bool = False,
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

    # ------------------------------------------------------------------ commands (loop thread)

    def _set_playing(self, playing: bool) -> None:
        self.playing = playing
        self._last_frame_time = None

    def _request_step(self) -> None:
        self.playing = False
        self._step_once = True

    def _read_speed(self) -> None:
        self.speed = 0.0 if self.gui.max_speed.value else float(self.gui.speed.value)

    def _apply_trails(self) -> None:
        if self.scene is not None:
            self.scene.set_trails_visible(bool(self.gui.trails.value))
            self._push_frame()

    def _seek(self, index: int) -> None:
        if isinstance(self.source, ReplaySource):
            self.source.seek(index)
            self._push_frame()

    def _reset(self, seed: int) -> None:
        if isinstance(self.source, ReplaySource):
            self.source.seek(0)
        elif isinstance(self.source, LiveSource):
            self.source.reset(seed)
            self.gui.seed.value = seed
            self._status(self._live_status())
        self._hold_until = None
        self._push_frame()

    def _live_status(self) -> str:
        assert isinstance(self.source, LiveSource)
        run = self.source.run
        pols = ", ".join(f"{t}s: `{run.policies[t].source}`" for t in TEAMS)
        return (
            f"**{self.mode}** `{run.config.name}` x{run.num_arenas}, {run.backend}, "
            f"seed {run.seed}; {pols}"
        )

    def _policies(
        self, config: EnvConfig, specs: dict[str, str], access: PolicyAccess | None
    ) -> dict[str, Policy]:
        """Each team's policy; a team whose policy fails falls back to scripted (error shown)."""
        out = {}
        deterministic = bool(self.gui.deterministic.value)
        for team in TEAMS:
            try:
                out[team] = load_team_policy(specs[team], config, team, deterministic, access)
            except PolicyError as err:
                self._report(f"{err} (the {team}s play scripted instead)")
                out[team] = load_team_policy("scripted", config, team)
        return out

    def _start_live(self) -> None:
        o = self.options
        config = get_preset(o.preset)
        self._status(f"compiling `{config.name}` ({o.backend})...")
        policies = self._policies(config, {"pursuer": o.pursuers, "evader": o.evaders}, None)
        run = LiveRun(config, policies, o.arenas, o.backend, o.seed)
        self._set_source(LiveSource(run, o.trail_length))
        self._status(self._live_status())

    def _scene_config(self) -> EnvConfig:
        base = get_preset(self.gui.preset.value)
        counts = (
            int(self.gui.pursuers.value),
            int(self.gui.evaders.value),
            int(self.gui.obstacles.value),
        )
        have = (base.pursuer.num_agents, base.evader.num_agents, base.arena.num_obstacles)
        return base if counts == have else base.with_counts(*counts)

    def _apply_scene(self) -> None:
        config = self._scene_config()  # ValueError (cannot be placed) is reported by the loop
        arenas = int(self.gui.arenas.value)
        backend = str(self.gui.backend.value)
        seed = int(self.gui.seed.value)
        if arenas < 1:
            raise ValueError(f"arenas must be >= 1, got {arenas}")
        specs = {
            "pursuer": str(self.gui.pursuer_policy.value),
            "evader": str(self.gui.evader_policy.value),
        }
        self._status(f"compiling `{config.name}` ({backend})...")
        policies = self._policies(config, specs, self.policy_access)
        run = LiveRun(config, policies, arenas, backend, seed)
        self._set_source(LiveSource(run, self.options.trail_length))
        self._clear_error()
        self._status(self._live_status())

    def _load_policies(self) -> None:
        if not isinstance(self.source, LiveSource):
            return
        run = self.source.run
        specs = {
            "pursuer": str(self.gui.pursuer_policy.value),
            "evader": str(self.gui.evader_policy.value),
        }
        deterministic = bool(self.gui.deterministic.value)
        failed = False
        for team in TEAMS:
            current = run.policies[team]
            same_mode = not current.learned or current.deterministic == deterministic
            if specs[team].strip() == current.source and same_mode:
                continue  # unchanged: no reload, no recompilation
            try:
                policy = load_team_policy(
                    specs[team], run.config, team, deterministic, self.policy_access
                )
            except PolicyError as err:
                self._report(f"{err} (the {team}s keep `{run.policies[team].source}`)")
                failed = True
                continue
            self._status(f"compiling the {team} policy...")
            run.set_policy(team, policy)
        if not failed:
            self._clear_error()
        self._status(self._live_status())
        self._push_frame()

    def _set_source(self, source: LiveSource | ReplaySource) -> None:
        rebuild = (
            self.scene is None
            or self.scene.config != source.config
            or self.scene.num_arenas != source.num_arenas
        )
        self.source = source
        if rebuild:
            if self.scene is not None:
                self.scene.remove()
            self.scene = ArenaScene(self.server, source.config, source.num_arenas)
            self.scene.set_trails_visible(bool(self.gui.trails.value))
            position, look_at = self.scene.camera_pose()
            self.server.initial_camera.position = position
            self.server.initial_camera.look_at = look_at
            for client in self.server.get_clients().values():
                client.camera.position = position
                client.camera.look_at = look_at
        if isinstance(source, ReplaySource):
            self.gui.frame.max = max(1, source.num_frames - 1)
            self._status(
                f"**replay** `{source.config.name}` x{source.num_arenas}, "
                f"{source.num_frames} frames"
            )
        self.gui.att_arena.max = source.num_arenas - 1
        self._hold_until = None
        self._push_frame()
        self._ready.set()

    # -- attention

    def _attention(self) -> Any:
        if not isinstance(self.source, LiveSource) or not self.gui.att_show.value:
            self.gui.att_info.content = ""
            return None
        run = self.source.run
        team = str(self.gui.att_team.value)
        arena = int(np.clip(int(self.gui.att_arena.value), 0, run.num_arenas - 1))
        agent = int(np.clip(int(self.gui.att_agent.value), 0, run.config.team(team).num_agents - 1))
        overlay = run.attention(team, arena, agent)
        if overlay is None:
            label = run.policies[team].source
            self.gui.att_info.content = (
                f"The {team} policy `{label}` has no attention weights (only MIX policies do)."
            )
            return None
        order = np.argsort(-overlay.weights)[:5]
        counts: dict[str, int] = {}
        names = []
        for kind in overlay.kinds:
            names.append(f"{kind[:-1]} {counts.get(kind, 0)}")
            counts[kind] = counts.get(kind, 0) + 1
        own = run.own_attention(team, arena, agent)
        top = ", ".join(f"{names[i]}: {overlay.weights[i]:.2f}" for i in order)
        self.gui.att_info.content = f"{team} {agent} in arena {arena}; self {own:.2f}; {top}"
        return overlay

    # -- recording

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

    # -- training view

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
        self._status(self._live_status())

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

    # ------------------------------------------------------------------ the loop

    def _push_frame_if_paused(self) -> None:
        if not self.playing:
            self._push_frame()

    def _push_frame(self) -> None:
        if self.source is None or self.scene is None:
            return
        trail = self.source.trail() if self.gui.trails.value else None
        if self._serializer is not None:
            now = time.monotonic()
            self._serializer.insert_sleep(max(now - self._last_record_time, 0.0))
            self._last_record_time = now
        self.scene.update(self.source.frame(), trail, self._attention())
        self.frames_streamed += 1
        if isinstance(self.source, ReplaySource):
            self.gui.frame.value = self.source.index
        now = time.monotonic()
        if now - self._last_counters >= COUNTER_PERIOD or not self.playing:
            self._last_counters = now
            label = "frame t" if isinstance(self.source, ReplaySource) else "t"
            self.gui.counters.content = counters_markdown(
                self.source.counters(), self.source.config, label
            )

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
    **overrides: Any,
) -> Viewer:
    """Starts the viewer (server, GUI, loop thread) and, with `wait`, blocks until the first frame.

    Args:
      options: the starting options; keyword `overrides` replace fields of it
        (``start_viewer(preset="4-1-2", port=0, backend="kinematic")``).
      replay: a trajectory to replay instead of a live run.
      training: an empty viewer fed by `Viewer.training_update` (``pe-mjx train --view``).
      wait: block until the first frame has been sent (not for `training`).
    """
    options = dataclasses.replace(options or ViewerOptions(), **overrides)
    viewer = Viewer(options, replay=replay, training=training)
    if wait and not training:
        try:
            viewer.wait_ready()
        except BaseException:
            viewer.stop()
            raise
    return viewer


__all__ = ["Viewer", "ViewerOptions", "start_viewer"]
