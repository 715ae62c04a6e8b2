"""tools/soak_viewer.py for seconds: two `pe-mjx view` processes, three tabs, a clean report."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from pe_mjx.trajectory import save
from tests.viewer.browser import require_chromium
from tests.viewer.viewer_helpers import LIVE_PRESET, synthetic_trajectory

ROOT = Path(__file__).resolve().parents[2]


def test_a_short_soak_writes_a_clean_report(tmp_path):
    require_chromium()
    replay = save(tmp_path / "pairing-0.npz", synthetic_trajectory())
    out, figure = tmp_path / "soak.json", tmp_path / "soak.png"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    args = ["--minutes", "0.1", "--interval", "2", "--preset", LIVE_PRESET, "--arenas", "1"]
    args += ["--replay", str(replay), "--out", str(out), "--figure", str(figure)]
    done = subprocess.run(
        [sys.executable, "-m", "tools.soak_viewer", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    report = json.loads(out.read_text())
    summary = report["summary"]
    assert report["errors"] == [] and summary["js_errors"] == 0, report["errors"]
    assert summary["ok"] and summary["tabs_stalled"] == [] and summary["viewers_died"] == []
    assert summary["viewer_exit_codes"] == {"live": 0, "replay": 0}
    samples = report["samples"]
    assert len(samples) >= 2 and samples[-1]["t_s"] >= 6  # a sample may take longer than 2 s
    for sample in samples:
        assert sample["rss_mb"]["live"] > 50 and sample["rss_mb"]["replay"] > 50
        assert sample["browser_rss_mb"] > 50
        assert all(sample["js_heap_mb"][tab] > 0.5 for tab in ("live-1", "live-2", "replay"))
    for tab in ("live-1", "live-2", "replay"):
        assert any(s["updating"][tab] for s in samples), tab
    trends = [*summary["rss"].values(), *summary["js_heap"].values()]
    assert len(trends) == 6 and all(v["slope_mb_per_min"] is not None for v in trends)
    assert report["machine"]["cpus"] == os.cpu_count() and report["date"]
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
