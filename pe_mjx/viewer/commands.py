"""The viewer's commands on its loop thread: playback, the scene, the policies, attention.

Split out of `pe_mjx.viewer.app` by role: `SceneCommands` is a mixin of `app.Viewer` (the one
class a caller sees), so the commands read and write the viewer's state directly, as they did
when they were its methods. Everything here runs on the loop thread only (`Viewer.post`), the one
thread that touches the source and the scene; viser's callbacks never call these directly.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.names import TEAMS
from pe_mjx.policy.core import Policy
from pe_mjx.viewer.guard import PolicyAccess
from pe_mjx.viewer.live import LiveRun, PolicyError, load_team_policy
from pe_mjx.viewer.replay import ReplaySource
from pe_mjx.viewer.scene import ArenaScene
from pe_mjx.viewer.sources import LiveSource


class SceneCommands:
    """Playback, scene and policy commands of `app.Viewer` (see the module docstring).

    The attributes below are the viewer's, set in `Viewer.__init__`; the methods the commands
    call back (`_push_frame`, `_status`, `_report`, `_clear_error`) are the app's."""

    gui: Any
    server: Any
    options: Any
    mode: str
    source: LiveSource | ReplaySource | None
    scene: ArenaScene | None
    playing: bool
    speed: float
    policy_access: PolicyAccess
    _resolved: dict[str, Policy] | None

    # ------------------------------------------------------------------ playback

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

    # ------------------------------------------------------------------ scene and policies

    def _live_status(self, source: LiveSource | None = None) -> str:
        """The status line of a live source (`self.source` unless given)."""
        source = self.source if source is None else source
        assert isinstance(source, LiveSource)
        run = source.run
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
        policies, self._resolved = self._resolved, None  # the caller's, once
        if policies is None:
            policies = self._policies(config, {"pursuer": o.pursuers, "evader": o.evaders}, None)
        run = LiveRun(config, policies, o.arenas, o.backend, o.seed)
        self._set_source(LiveSource(run, o.trail_length))

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
        self._clear_error()
        self._set_source(LiveSource(run, self.options.trail_length))

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
        """Shows `source`: its scene (rebuilt if the scene changed), its first frame and its
        status line, then publishes it as `self.source`.

        Publishing comes last on purpose. Other threads read `self.source` to learn that the
        viewer switched (`wait_ready`, scripts, the tests); once they see the new source,
        everything a page needs to show it (scene, frame, status naming the scene) is already
        queued on the server, so a page is never waited for before it was sent anything. (It
        used to be assigned first: a reader then saw the new scene's size while the page still
        had the old scene and the old status, and only the compile-time status told it the new
        name.)"""
        rebuild = (
            self.scene is None
            or self.scene.config != source.config
            or self.scene.num_arenas != source.num_arenas
        )
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
        else:
            self._status(self._live_status(source))
        self.gui.att_arena.max = source.num_arenas - 1
        self._hold_until = None
        self._push_frame(source)
        self.source = source
        self._ready.set()

    # ------------------------------------------------------------------ attention

    def _attention(self, source: LiveSource | ReplaySource | None = None) -> Any:
        """The attention overlay to draw for `source` (`self.source` unless given), or None."""
        source = self.source if source is None else source
        if not isinstance(source, LiveSource) or not self.gui.att_show.value:
            self.gui.att_info.content = ""
            return None
        run = source.run
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


__all__ = ["SceneCommands"]
