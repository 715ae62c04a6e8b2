"""`pe-mjx view`: watch arenas live in the browser, replay a trajectory, or export either as a
page that plays without a server.

Each policy is resolved once, here, with --deterministic as given: a bad or damaged one is one
error line before the server starts, and the export plays the very policies that were checked.
The export honours every option of the live view that a recording can show (the scene, the
policies and --deterministic, --arenas, --backend, --seed, --speed, --trails and
--trail-length); --loop, --hold, --play and the server's own flags concern a running page only.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Annotated

import tyro

from pe_mjx import interrupts
from pe_mjx.commands.common import check_preset, check_writable_dir, fail, one_line
from pe_mjx.names import BACKENDS, TEAMS
from pe_mjx.viewer.options import ViewerOptions


@dataclasses.dataclass(frozen=True)
class ViewArgs:
    """Watch arenas live in the browser (Viser), replay recorded trajectories, export recordings.

    Prints the local URL; the page shows the arenas in 3D and updates live. With --export it
    writes <export>.viser and <export>.html (a page that plays without a server) and exits."""

    viewer: Annotated[ViewerOptions, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=ViewerOptions
    )
    replay: Path | None = None
    """Replay this trajectory file (.npz written by `pe-mjx evaluate`) instead of a live run."""
    export: Path | None = None
    """Write <export>.viser and <export>.html and exit (the replay, or --steps live steps)."""
    steps: int = 200
    """Live control steps recorded by --export."""


def load_policies(options: ViewerOptions) -> dict:
    """--pursuers and --evaders resolved for the preset (greedy with --deterministic), each
    failure one error line naming its flag."""
    from pe_mjx.config import get_preset
    from pe_mjx.viewer.live import PolicyError, load_team_policy

    config = get_preset(options.preset)
    specs = {"pursuer": ("--pursuers", options.pursuers), "evader": ("--evaders", options.evaders)}
    policies = {}
    for team, (flag, spec) in specs.items():
        try:
            policies[team] = load_team_policy(spec, config, team, options.deterministic)
        except Exception as err:  # a damaged checkpoint too: one line, never a traceback
            text = one_line(err)
            if not isinstance(err, PolicyError):
                text = f"cannot load the policy {spec!r} ({type(err).__name__}: {text})"
            fail(f"{flag}: {text}")
    return policies


def check_view_args(args: ViewArgs) -> None:
    from pe_mjx.viewer.guard import MAX_ARENAS, SEED_MAX, check_address

    o = args.viewer
    if o.arenas is not None and not 1 <= o.arenas <= MAX_ARENAS:
        fail(f"--arenas must be in 1..{MAX_ARENAS}, got {o.arenas}")
    if o.backend not in BACKENDS:
        fail(f"--backend: unknown backend {o.backend!r}; expected {' or '.join(BACKENDS)}")
    if not 0 <= o.seed <= SEED_MAX:
        fail(f"--seed must be in 0..{SEED_MAX}, got {o.seed}")
    if not math.isfinite(o.speed) or o.speed < 0:
        fail(f"--speed must be a finite number >= 0, got {o.speed}")
    if args.steps < 1:
        fail(f"--steps must be >= 1, got {args.steps}")
    if o.trail_length < 1:
        fail(f"--trail-length must be >= 1, got {o.trail_length}")
    if not math.isfinite(o.hold) or o.hold < 0:
        fail(f"--hold must be a finite number >= 0, got {o.hold}")
    for root in o.policy_roots or ():
        if not root.is_dir():
            fail(f"--policy-roots: {root} is not a directory")
    if args.export is not None:
        from pe_mjx import sizes
        from pe_mjx.config import get_preset

        try:
            sizes.check_recording(get_preset(o.preset), o.arenas or 1, args.steps)
        except ValueError as err:
            fail(str(err))
        for suffix in (".viser", ".html"):
            if args.export.with_suffix(suffix).exists():
                fail(f"--export: {args.export.with_suffix(suffix)} exists; refusing to overwrite")
        check_writable_dir("--export", args.export.parent)
        return
    check_writable_dir("--record-dir", o.record_dir)
    try:
        check_address(o.host, o.port)  # the viewer warns about a non-local address
    except ValueError as err:
        fail(str(err))


def run_view(args: ViewArgs) -> None:
    from pe_mjx.trajectory import TrajectoryError

    check_view_args(args)
    traj, policies = None, None
    if args.replay is not None:
        from pe_mjx.trajectory import load as load_trajectory

        try:
            traj = load_trajectory(args.replay).select(args.viewer.arenas or 16)
        except TrajectoryError as err:
            fail(str(err))
    else:
        check_preset(args.viewer.preset)
        policies = load_policies(args.viewer)
    if args.export is not None:
        try:
            paths = export(args.viewer, args.export, args.steps, traj, policies)
        except (FileExistsError, TrajectoryError) as err:
            fail(str(err))
        print(f"wrote {paths[0]} and {paths[1]}")
        return
    serve(args.viewer, traj, policies)


def export(
    options: ViewerOptions, stem: Path, steps: int, traj=None, policies: dict | None = None
) -> tuple[Path, Path]:
    """A replay (`traj`), or `steps` live steps of `policies`, as `<stem>.viser` and `.html`."""
    from pe_mjx.viewer.replay import ReplaySource, export_recording

    speed = options.speed / 5.0 if options.speed > 0 else 1.0  # 5 env steps/s is real time
    if traj is not None:
        source = ReplaySource(traj, options.trail_length)

        def frames():
            for t in range(traj.num_frames):
                source.seek(t)
                yield source.frame(), source.trail() if options.trails else None

        config, arenas = traj.config, traj.num_arenas
    else:
        frames, config, arenas = _live_frames(options, steps, policies)
    return export_recording(config, arenas, frames(), stem, config.control_dt / max(speed, 1e-6))


def _live_frames(options: ViewerOptions, steps: int, policies: dict):
    """(frames, scene, arenas) of at most `steps` live steps (until every arena is done)."""
    from pe_mjx.config import get_preset
    from pe_mjx.viewer.live import LiveRun
    from pe_mjx.viewer.scene import TrailBuffer

    config = get_preset(options.preset)
    arenas = options.arenas or 1
    run = LiveRun(config, {t: policies[t] for t in TEAMS}, arenas, options.backend, options.seed)
    trails = TrailBuffer(options.trail_length)

    def frames():
        for i in range(steps + 1):
            interrupts.check()  # a safe point between frames (Ctrl-C)
            if i:
                if run.done:
                    break
                run.step()
            trails.push(run.positions())
            yield run.frame(), trails.array() if options.trails else None

    return frames, config, arenas


def serve(options: ViewerOptions, traj=None, policies: dict | None = None) -> None:
    """Serves the viewer until Ctrl-C (a replay in its own scene)."""
    from pe_mjx.viewer.app import start_viewer

    if traj is not None:
        options = dataclasses.replace(options, preset=traj.config.name)
    viewer = None
    try:  # a Ctrl-C at any point from here on stops the server it started
        viewer = start_viewer(options, replay=traj, wait=False, policies=policies)
        print(f"pe-mjx view: open {viewer.url} in a browser (Ctrl-C stops the server)", flush=True)
        while True:
            # Short sleeps: a SIGINT delivered to another thread (the server's) only sets a flag
            # that this thread checks when its sleep returns; a long sleep held Ctrl-C back for
            # up to an hour (a CI test that hung). The Ctrl-C handler records the signal;
            # this loop's safe point raises it (pe_mjx.interrupts).
            interrupts.sleep(0.2)
    except KeyboardInterrupt:
        interrupts.handled()  # Ctrl-C is how the server is stopped: its normal end, exit 0
    finally:
        if viewer is not None:
            viewer.stop()
