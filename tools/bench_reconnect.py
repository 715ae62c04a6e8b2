"""How long a tab takes to get back after its connection drops, by websocket handshake latency.

A live viewer (4-1-2, scripted pursuers, a random evader, 2 arenas, kinematic) is opened in one
headless Chromium tab through `ConnectionProxy`, which holds each websocket handshake
``delay`` seconds (a slow or tunnelled link). Once the tab plays, the proxy cuts its connection;
the tool then times how long until the server has the tab again and has streamed a frame to it,
up to ``--budget`` seconds, and counts the handshakes viser's client tried meanwhile. Writes the
rows, the machine and the date as JSON.

    .venv/bin/python -m tools.bench_reconnect                    # docs/bench_reconnect.json
    .venv/bin/python -m tools.bench_reconnect --delays 0 1.5 --budget 30

Why it exists: viser's client (1.1.1) retries a lost connection every second and each retry
closes the attempt still in flight, so a link whose handshake takes longer than that never
gets back (the viewer's browser tests met a page that stopped updating once under load).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import viser

from pe_mjx.bench import machine
from pe_mjx.viewer import start_viewer
from pe_mjx.viewer.browser import (
    LIVE_VIEWER,
    Browser,
    ConnectionProxy,
    shows_both_teams,
)

DELAYS = (0.0, 0.25, 0.5, 0.75, 0.9, 1.1, 1.5, 2.0)


def _wait(predicate, budget: float) -> float | None:
    start = time.monotonic()
    while time.monotonic() - start < budget:
        if predicate():
            return time.monotonic() - start
        time.sleep(0.05)
    return None


def measure(viewer, browser: Browser, delay: float, budget: float) -> dict:
    proxy = ConnectionProxy(viewer.port, handshake_delay=delay)
    page = browser.new_page(proxy.url)
    try:
        opened = _wait(
            lambda: viewer.num_clients() == 1 and shows_both_teams(page.screenshot()), budget
        )
        if opened is None:
            return {"delay": delay, "first_connect": False}
        tries = proxy.handshakes
        proxy.drop()
        if _wait(lambda: viewer.num_clients() == 0, 10.0) is None:
            return {"delay": delay, "first_connect": True, "dropped": False}
        frames = viewer.frames_streamed
        back = _wait(lambda: viewer.num_clients() == 1 and viewer.frames_streamed > frames, budget)
        return {
            "delay": delay,
            "first_connect": True,
            "dropped": True,
            "back_after_s": None if back is None else round(back, 2),
            "handshakes_tried": proxy.handshakes - tries,
        }
    finally:
        page.close()
        proxy.close()
        _wait(lambda: viewer.num_clients() == 0, 10.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--delays", type=float, nargs="+", default=list(DELAYS))
    parser.add_argument("--budget", type=float, default=60.0, help="seconds to wait per step")
    parser.add_argument("--out", type=Path, default=Path("docs/bench_reconnect.json"))
    args = parser.parse_args()
    viewer = start_viewer(**LIVE_VIEWER, port=0, verbose=False)
    rows = []
    try:
        with Browser.launch() as browser:
            for delay in args.delays:
                row = measure(viewer, browser, delay, args.budget)
                print(json.dumps(row), flush=True)
                rows.append(row)
    finally:
        viewer.stop()
    result = {
        "machine": machine(),
        "viser": viser.__version__,
        "budget_s": args.budget,
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
