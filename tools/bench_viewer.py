"""Frame rate of the viewer: env steps streamed per second to a connected browser.

Starts the viewer (``--arenas`` arenas of ``--preset``, scripted teams by default) at full speed
("Max speed": no pacing, finished episodes restart at once), connects one headless Chromium tab
(software WebGL, on the same machine), and counts the frames the server pushed over ``--seconds``:
each frame is one control step of every arena plus one atomic scene update. It also checks that
the default 10 steps/s pacing is met. Writes the results as JSON and one screenshot.

    .venv/bin/python -m tools.bench_viewer                     # 24-6-12, 4 arenas, both backends
    .venv/bin/python -m tools.bench_viewer --backends kinematic --seconds 10

Run it as a module from the checkout: it drives Chromium with `pe_mjx.viewer.browser` (Playwright on
Debian's chromium), the driver the viewer tests use too.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
from PIL import Image

from pe_mjx.viewer import start_viewer
from pe_mjx.viewer.browser import (
    Browser,
    find_chromium,
    shows_both_teams,
)

HIDE_NOTIFICATIONS = (
    "document.querySelectorAll('[class*=\"Notification-root\"]').forEach(e => e.remove()); true"
)


def measure(args: argparse.Namespace, backend: str, browser: Browser, shot: Path | None) -> dict:
    t0 = time.perf_counter()
    viewer = start_viewer(
        preset=args.preset,
        pursuers=args.pursuers,
        evaders=args.evaders,
        arenas=args.arenas,
        backend=backend,
        port=0,
        speed=0.0,
        hold=0.0,
        verbose=False,
        play=False,
    )
    startup = time.perf_counter() - t0
    try:
        page = browser.new_page(viewer.url)
        page.wait_for_image(shows_both_teams, timeout=180)
        viewer.play()
        time.sleep(1.0)  # warm: first frames after play
        f0, t0 = viewer.frames_streamed, time.perf_counter()
        time.sleep(args.seconds)
        frames, seconds = viewer.frames_streamed - f0, time.perf_counter() - t0
        max_rate = frames / seconds

        viewer.gui.max_speed.value = False
        viewer.gui.speed.value = 10.0
        wait = time.monotonic() + 10
        while viewer.speed != 10.0 and time.monotonic() < wait:
            time.sleep(0.05)
        time.sleep(1.0)
        f0, t0 = viewer.frames_streamed, time.perf_counter()
        time.sleep(min(args.seconds, 5.0))
        paced = (viewer.frames_streamed - f0) / (time.perf_counter() - t0)
        if shot is not None:
            # Early in a fresh episode, at 10 steps/s: both teams on screen, short trails.
            viewer.gui.att_show.value = True
            viewer.reset(args.seed)
            page.evaluate(HIDE_NOTIFICATIONS)
            time.sleep(4.0)
            viewer.pause()
            time.sleep(1.0)
            image = page.screenshot()
            if not shows_both_teams(image):
                raise RuntimeError("the screenshot does not show both teams")
            shot.parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(image).save(shot)
        page.close()
    finally:
        viewer.stop()
    result = {
        "backend": backend,
        "startup_s": round(startup, 1),
        "max_speed_steps_per_s": round(max_rate, 1),
        "max_speed_agent_steps_per_s": round(max_rate * args.arenas * _agents(args.preset), 1),
        "paced_10_steps_per_s": round(paced, 1),
        "frames": frames,
        "seconds": round(seconds, 2),
    }
    print(json.dumps(result), flush=True)
    return result


def _agents(preset: str) -> int:
    from pe_mjx.config import get_preset

    return get_preset(preset).num_agents


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="24-6-12")
    parser.add_argument("--arenas", type=int, default=4)
    parser.add_argument("--backends", nargs="+", default=["kinematic", "mjx"])
    parser.add_argument("--pursuers", default="scripted")
    parser.add_argument("--evaders", default="scripted")
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--seed", type=int, default=0, help="episode seed of the screenshot")
    parser.add_argument("--out", type=Path, default=Path("docs/bench_viewer.json"))
    parser.add_argument("--screenshot", type=Path, default=Path("docs/viewer.png"))
    args = parser.parse_args()
    if find_chromium() is None:
        sys.exit("bench_viewer: needs Chromium (apt-get install chromium)")
    results = []
    load_before = os.getloadavg()[0]
    with Browser.launch() as browser:
        for i, backend in enumerate(args.backends):
            results.append(measure(args, backend, browser, args.screenshot if i == 0 else None))
    report = {
        "what": "env steps streamed per second by the viewer to one connected browser tab "
        "(each step = one control step of every arena + one atomic scene update)",
        "preset": args.preset,
        "arenas": args.arenas,
        "pursuers": args.pursuers,
        "evaders": args.evaders,
        "client": "headless Chromium, software WebGL (SwiftShader), same machine",
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "jax": jax.__version__,
            "device": str(jax.devices()[0]),
            "load_average_1min_at_start": round(load_before, 2),
        },
        "date": time.strftime("%Y-%m-%d"),
        "results": results,
        "screenshot": str(args.screenshot),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out} and {args.screenshot}")


if __name__ == "__main__":
    main()
