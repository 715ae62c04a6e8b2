"""Fixtures of the viewer tests: headless Chromium, a live viewer, a replay, a tiny trained run.

Browser tests need Debian's `chromium`; without it they skip, except under CI=true, where they
fail (`require_chromium`). Everything that compiles (the live viewer, the tiny training run) is
session-scoped and shared: on the 2-core CI machine each JAX compile costs tens of seconds.
"""

from __future__ import annotations

import dataclasses
import functools
import http.server
import threading
from pathlib import Path

import pytest

from pe_mjx.trajectory import Trajectory
from tests.viewer.browser import LIVE_VIEWER, Browser, require_chromium
from tests.viewer.viewer_helpers import synthetic_trajectory, wait_until


@pytest.fixture(scope="session")
def browser():
    require_chromium()
    b = Browser.launch()
    yield b
    b.close()


@pytest.fixture(scope="session")
def live_viewer(tmp_path_factory):
    """Scripted pursuers against a random evader, two arenas, kinematic backend, 15 steps/s; the
    page may open policy runs under the session's temporary directory (the tiny run's)."""
    from pe_mjx.viewer import start_viewer

    viewer = start_viewer(
        **LIVE_VIEWER,
        port=0,
        verbose=False,
        record_dir=tmp_path_factory.mktemp("recordings"),
        policy_roots=(tmp_path_factory.getbasetemp(),),
    )
    yield viewer
    viewer.stop()


@pytest.fixture(scope="session")
def trajectory() -> Trajectory:
    return synthetic_trajectory()


@dataclasses.dataclass
class TinyRun:
    run_dir: Path
    viewer: object
    iterations: int


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory):
    """Three PPO iterations (MIX pursuer learned, scripted evader) on 2-1-1 with the training view
    attached, as `pe-mjx train --view` wires it. The viewer stays up for the session."""
    from pe_mjx.ppo.run import train
    from pe_mjx.viewer import start_viewer
    from tests.tiny_config import tiny

    config = tiny(
        preset="2-1-1",
        **{
            "evader.policy": "scripted",
            "env_steps": 24,
            "ppo.num_envs": 2,
            "ppo.unroll_length": 4,
            "ppo.num_minibatches": 1,
            "checkpoint_every": 1,
            "pursuer.network.width": 8,
            "pursuer.network.num_heads": 2,
            "pursuer.network.hidden": 16,
        },
    )
    viewer = start_viewer(training=True, port=0, verbose=False)
    run_dir = tmp_path_factory.mktemp("train") / "run"
    try:
        _, state = train(config, run_dir, progress=False, on_iteration=viewer.training_update)
        wait_until(lambda: viewer.source is not None, timeout=600, what="the training view")
    except BaseException:
        viewer.stop()
        raise
    yield TinyRun(run_dir=run_dir, viewer=viewer, iterations=int(state.iteration))
    viewer.stop()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass


@pytest.fixture
def static_server():
    """serve(directory) -> base URL of a static HTTP server on 127.0.0.1 (stopped afterwards)."""
    servers = []

    def serve(directory: Path) -> str:
        handler = functools.partial(_QuietHandler, directory=str(directory))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_address[1]}"

    yield serve
    for server in servers:
        server.shutdown()
        server.server_close()
