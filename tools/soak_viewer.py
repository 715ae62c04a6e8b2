"""Soak of the viewer: memory, page errors and live updates over a long run with three tabs open.

Starts two viewers as `pe-mjx view` subprocesses, as a person would: live arenas (``--preset``,
``--arenas``, kinematic backend, scripted teams, 10 steps/s) and a replay of a trajectory file
(``--replay``; by default one that `pe-mjx evaluate` writes first). Opens three headless Chromium
tabs (pe_mjx/viewer/browser.py: Playwright on Debian's chromium, software WebGL): two on the live
viewer, one on the replay. Then, every ``--interval`` seconds for ``--minutes``, it samples the
resident memory (RSS) of each viewer process and of the browser's processes, each tab's
JavaScript heap, the JavaScript errors each tab reported (console.error, uncaught exceptions, a
renderer crash), and whether each tab still updates (its robots' pixels changed since the
previous sample). Writes a JSON report (machine, date, samples, errors, memory slopes in MB/min
fitted after ``--warmup`` minutes) and a figure of memory over time. Exits 1 if a tab logged an
error or stalled, or a viewer died or did not stop cleanly.

    .venv/bin/python -m tools.soak_viewer       # 10 min: docs/soak_viewer.json, docs/figures/...
    .venv/bin/python -m tools.soak_viewer --minutes 0.1 --out /tmp/soak.json --figure /tmp/soak.png

It imports the browser driver it shares with the viewer tests from the package
(`pe_mjx.viewer.browser`).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil
from playwright.sync_api import Error as PlaywrightError

from pe_mjx.plots import save_palette_png
from pe_mjx.viewer.browser import Browser, BrowserError, find_chromium, scene_region, team_pixels

CLI = [sys.executable, "-m", "pe_mjx.cli"]
MOVED_PIXELS = 50  # robot pixels that must change between two samples: the tab updated
START_TIMEOUT = 600.0  # seconds for a viewer to print its URL and a tab to show both teams


def robots_mask(image: np.ndarray) -> np.ndarray:
    masks = team_pixels(scene_region(image))
    return masks["pursuer"] | masks["evader"]


def shows_both_teams(image: np.ndarray) -> bool:
    return all(int(m.sum()) >= 20 for m in team_pixels(scene_region(image)).values())


class ViewerProcess:
    """`pe-mjx view ARGS --port 0` in a subprocess: its URL, its last output lines, its RSS."""

    def __init__(self, name: str, args: list[str]):
        self.name = name
        self.command = [*CLI, "view", *args, "--port", "0"]
        self.proc = subprocess.Popen(
            self.command,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
        )
        self.lines: collections.deque[str] = collections.deque(maxlen=100)
        self.url: str | None = None
        self._printed = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:  # drained to the end: the viewer never blocks on a pipe
            self.lines.append(line.rstrip())
            match = re.search(r"open (http://127\.0\.0\.1:\d+)", line)
            if match and self.url is None:
                self.url = match.group(1)
                self._printed.set()
        self._printed.set()

    def wait_url(self, timeout: float) -> str:
        self._printed.wait(timeout)
        if self.url is None:
            tail = "\n".join(list(self.lines)[-20:])
            raise RuntimeError(
                f"the {self.name} viewer printed no URL ({self.proc.poll()}):\n{tail}"
            )
        return self.url

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def rss_mb(self) -> float | None:
        """RSS of the viewer process (and any children), MB; None once it is gone."""
        try:
            root = psutil.Process(self.proc.pid)
            return _rss_mb([root, *root.children(recursive=True)])
        except psutil.NoSuchProcess:
            return None

    def stop(self) -> int | None:
        """Ctrl-C, as a person stops it; killed after 30 s. Returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=30)
        return self.proc.returncode


def _rss_mb(processes: list[psutil.Process]) -> float:
    total = 0
    for process in processes:
        with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
            total += process.memory_info().rss
    return round(total / 2**20, 1)


def browser_rss_mb() -> float:
    """Summed RSS of this process's Chromium descendants, MB (pages they share count in each)."""
    processes = []
    for child in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.NoSuchProcess, psutil.AccessDenied):
            if "chrom" in child.name():
                processes.append(child)
    return _rss_mb(processes)


def make_replay(preset: str, directory: Path) -> tuple[Path, str]:
    """A trajectory file written by `pe-mjx evaluate` (scripted against scripted)."""
    out = directory / "evaluate"
    args = ["evaluate", "--pursuers", "scripted", "--evaders", "scripted", "--preset", preset]
    args += ["--trials", "2", "--record", "2", "--backend", "kinematic", "--no-progress"]
    args += ["--out", str(out)]
    done = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        raise RuntimeError(f"pe-mjx evaluate failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return out / "trajectories" / "pairing-0.npz", "pe-mjx " + " ".join(args[:-2])


def slope_mb_per_min(
    times_s: list[float], values: list[float | None], after_s: float
) -> float | None:
    """Least-squares slope of `values` over the samples at or after `after_s`, MB per minute
    (None with fewer than two)."""
    points = [
        (t, v) for t, v in zip(times_s, values, strict=True) if t >= after_s and v is not None
    ]
    if len(points) < 2:
        return None
    t, v = np.asarray(points, dtype=float).T
    return round(float(np.polyfit(t / 60.0, v, 1)[0]), 3) + 0.0  # never -0.0


def soak(args: argparse.Namespace, browser: Browser, viewers: dict[str, ViewerProcess]) -> dict:
    urls = {name: viewer.wait_url(START_TIMEOUT) for name, viewer in viewers.items()}
    tabs = {"live-1": urls["live"], "live-2": urls["live"], "replay": urls["replay"]}
    pages, last = {}, {}
    for name, url in tabs.items():
        pages[name] = browser.new_page(url)
        last[name] = robots_mask(pages[name].wait_for_image(shows_both_teams, START_TIMEOUT))
    seen = dict.fromkeys(tabs, 0)  # errors of each tab already reported
    still = dict.fromkeys(tabs, 0)  # samples in a row without change
    longest_still = dict.fromkeys(tabs, 0)
    samples, errors = [], []
    start = time.monotonic()
    tick = 0
    while True:
        tick += 1
        time.sleep(max(0.0, start + tick * args.interval - time.monotonic()))
        t = round(time.monotonic() - start, 1)
        updating, heap = {}, {}
        for name, page in pages.items():
            try:
                mask = robots_mask(page.screenshot())
                changed = int(np.sum(mask ^ last[name]))
                last[name] = mask
                heap[name] = round(page.js_heap_mb(), 2)
            except (BrowserError, PlaywrightError) as err:
                page.errors.append(f"sampling failed: {err}")
                changed, heap[name] = 0, None
            updating[name] = changed > MOVED_PIXELS
            still[name] = 0 if updating[name] else still[name] + 1
            longest_still[name] = max(longest_still[name], still[name])
            for message in page.errors[seen[name] :]:
                errors.append({"t_s": t, "tab": name, "message": message})
            seen[name] = len(page.errors)
        sample = {
            "t_s": t,
            "rss_mb": {name: viewer.rss_mb() for name, viewer in viewers.items()},
            "browser_rss_mb": browser_rss_mb(),
            "js_heap_mb": heap,
            "updating": updating,
            "errors": len(errors),
            "load_1min": round(os.getloadavg()[0], 2),
        }
        samples.append(sample)
        print(json.dumps(sample), flush=True)
        dead = [name for name, viewer in viewers.items() if not viewer.alive]
        if dead or t >= args.minutes * 60:
            break
    for page in pages.values():
        page.close()
    return {
        "samples": samples,
        "errors": errors,
        "longest_still": longest_still,
        "dead": dead,
    }


def _trend(times: list[float], values: list[float | None], warmup_s: float) -> dict:
    known = [v for v in values if v is not None]
    return {
        "first_mb": known[0] if known else None,
        "last_mb": known[-1] if known else None,
        "max_mb": max(known) if known else None,
        "slope_mb_per_min": slope_mb_per_min(times, values, warmup_s),
    }


def summarize(args: argparse.Namespace, result: dict, exits: dict[str, int | None]) -> dict:
    samples = result["samples"]
    times = [s["t_s"] for s in samples]
    duration = times[-1] if times else 0.0
    # The warm-up is left out of the slopes, but never more than the first half of the samples.
    warmup = min(args.warmup * 60, times[(len(times) - 1) // 2]) if times else 0.0
    series = {name: [s["rss_mb"][name] for s in samples] for name in ("live", "replay")}
    series["browser"] = [s["browser_rss_mb"] for s in samples]
    rss = {name: _trend(times, values, warmup) for name, values in series.items()}
    heap = {
        tab: _trend(times, [s["js_heap_mb"][tab] for s in samples], warmup)
        for tab in result["longest_still"]
    }
    stalled = [tab for tab, n in result["longest_still"].items() if n >= args.stall_samples]
    return {
        "duration_min": round(duration / 60, 2),
        "samples": len(samples),
        "mean_sample_spacing_s": round(duration / len(samples), 1) if samples else None,
        "js_errors": len(result["errors"]),
        "tabs_stalled": stalled,
        "longest_still_samples": result["longest_still"],
        "viewers_died": result["dead"],
        "viewer_exit_codes": exits,
        "slope_fitted_after_s": round(warmup, 1),
        "rss": rss,
        "js_heap": heap,
        "ok": not result["errors"]
        and not stalled
        and not result["dead"]
        and all(code == 0 for code in exits.values()),
    }


def _slope(rss: dict) -> str:
    slope = rss["slope_mb_per_min"]
    return "slope n/a" if slope is None else f"{slope:+.2f} MB/min"


def plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = report["samples"]
    minutes = [s["t_s"] / 60 for s in samples]
    rss = report["summary"]["rss"]
    fig, (top, bottom, heap) = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for name, label in (("live", "live viewer (2 tabs)"), ("replay", "replay viewer (1 tab)")):
        values = [np.nan if s["rss_mb"][name] is None else s["rss_mb"][name] for s in samples]
        top.plot(minutes, values, label=f"{label}: {_slope(rss[name])}")
    top.set_ylabel("viewer process RSS (MB)")
    top.legend(loc="best")
    top.grid(alpha=0.3)
    values = [s["browser_rss_mb"] for s in samples]
    label = f"Chromium, 3 tabs: {_slope(rss['browser'])}"
    bottom.plot(minutes, values, color="tab:green", label=label)
    bottom.set_ylabel("browser RSS, summed (MB)")
    bottom.legend(loc="best")
    bottom.grid(alpha=0.3)
    for tab, trend in report["summary"]["js_heap"].items():
        values = [np.nan if s["js_heap_mb"][tab] is None else s["js_heap_mb"][tab] for s in samples]
        heap.plot(minutes, values, label=f"{tab}: {_slope(trend)}")
    heap.set_ylabel("JS heap in use (MB)")
    heap.set_xlabel("minutes")
    heap.legend(loc="best")
    heap.grid(alpha=0.3)
    summary = report["summary"]
    fig.suptitle(
        f"Viewer soak, {report['date']}: {summary['duration_min']} min, "
        f"{summary['js_errors']} JS errors, stalled tabs: {len(summary['tabs_stalled'])}"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    save_palette_png(fig, path, dpi=100)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--interval", type=float, default=5.0, help="seconds between samples")
    parser.add_argument("--warmup", type=float, default=1.0, help="minutes left out of the slope")
    parser.add_argument(
        "--stall-samples", type=int, default=3, help="samples in a row without change: stalled"
    )
    parser.add_argument("--preset", default="20-5-8")
    parser.add_argument("--arenas", type=int, default=2)
    parser.add_argument(
        "--replay", type=Path, help="trajectory .npz (default: evaluate writes one)"
    )
    parser.add_argument("--out", type=Path, default=Path("docs/soak_viewer.json"))
    parser.add_argument("--figure", type=Path, default=Path("docs/figures/soak_viewer.png"))
    args = parser.parse_args()
    if find_chromium() is None:
        sys.exit("soak_viewer: needs Chromium (apt-get install chromium)")
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="pe-mjx-soak-") as tmp:
        if args.replay is None:
            print(f"writing a replay with pe-mjx evaluate ({args.preset})...", flush=True)
            replay, replay_from = make_replay(args.preset, Path(tmp))
        else:
            replay, replay_from = args.replay, str(args.replay)
        live_args = ["--preset", args.preset, "--arenas", str(args.arenas)]
        live_args += ["--backend", "kinematic", "--pursuers", "scripted", "--evaders", "scripted"]
        viewers = {
            "live": ViewerProcess("live", [*live_args, "--record-dir", f"{tmp}/rec-live"]),
            "replay": ViewerProcess(
                "replay", ["--replay", str(replay), "--record-dir", f"{tmp}/rec-replay"]
            ),
        }
        try:
            with Browser.launch() as browser:
                chromium = browser.version
                result = soak(args, browser, viewers)
        finally:
            exits = {name: viewer.stop() for name, viewer in viewers.items()}
            logs = {name: list(viewer.lines)[-20:] for name, viewer in viewers.items()}
    report = {
        "what": "viewer soak: two tabs on live arenas and one on a replay, served by two "
        "`pe-mjx view` processes; RSS of each viewer process and of the browser, JS errors of "
        "each tab (console.error, uncaught exceptions, renderer crash), and whether each tab's "
        f"robots moved since the previous sample (> {MOVED_PIXELS} pixels changed)",
        "command": "python -m tools.soak_viewer " + " ".join(sys.argv[1:]),
        "date": time.strftime("%Y-%m-%d"),
        "machine": {
            "cpus": os.cpu_count(),
            "memory_gb": round(psutil.virtual_memory().total / 2**30, 1),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "chromium": chromium,
            "load_average_at_start": [round(x, 2) for x in load_before],
            "load_average_at_end": [round(x, 2) for x in os.getloadavg()],
        },
        "live": {
            "command": "pe-mjx view " + " ".join(live_args),
            "tabs": ["live-1", "live-2"],
        },
        "replay": {"trajectory": replay_from, "tabs": ["replay"]},
        "interval_s": args.interval,
        "summary": summarize(args, result, exits),
        "errors": result["errors"],
        "viewer_last_lines": logs,
        "samples": result["samples"],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    plot(report, args.figure)
    print(json.dumps(report["summary"], indent=2))
    print(f"wrote {args.out} and {args.figure}")
    if not report["summary"]["ok"]:
        sys.exit(1)


if __name__ == "__main__":
    main()
