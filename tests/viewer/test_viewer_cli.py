"""`pe-mjx view` for real, through a subprocess: flags, errors, export, the served page."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time

import pytest
from viewer_helpers import shows_both_teams, synthetic_trajectory

from pe_mjx.trajectory import save

CLI = [sys.executable, "-m", "pe_mjx.cli"]


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*CLI, *args], capture_output=True, text=True, timeout=timeout, env=_env()
    )


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture(scope="module")
def trajectory_file(tmp_path_factory):
    return save(tmp_path_factory.mktemp("traj") / "pairing-0.npz", synthetic_trajectory())


def test_help_lists_the_flags():
    out = run("view", "--help")
    assert out.returncode == 0, out.stderr
    for flag in ("--replay", "--export", "--host", "--port", "--pursuers", "--arenas"):
        assert flag in out.stdout
    out = run("train", "--help")
    assert out.returncode == 0 and "--view" in out.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--preset", "nope"), "unknown preset 'nope'"),
        (("--replay", "/no/such/file.npz"), "no such file"),
        (("--arenas", "0"), "--arenas must be >= 1"),
        (("--backend", "warp"), "unknown backend"),
    ],
)
def test_bad_arguments_exit_2_with_a_clear_error(args, message):
    out = run("view", *args)
    assert out.returncode == 2
    assert message in out.stderr


def test_export_of_a_replay_writes_viser_and_html_and_never_overwrites(trajectory_file, tmp_path):
    stem = tmp_path / "out" / "pairing-0"
    out = run("view", "--replay", str(trajectory_file), "--export", str(stem))
    assert out.returncode == 0, out.stderr
    viser_file, html_file = stem.with_suffix(".viser"), stem.with_suffix(".html")
    assert viser_file.stat().st_size > 1000
    html = html_file.read_text()
    assert "__VISER_EMBED_DATA__" in html
    before = viser_file.read_bytes()
    out = run("view", "--replay", str(trajectory_file), "--export", str(stem))
    assert out.returncode == 2 and "exists" in out.stderr
    assert viser_file.read_bytes() == before


def test_served_page_from_the_cli(browser, trajectory_file):
    """`pe-mjx view --replay ... --port 0` prints the URL; the page shows both teams; Ctrl-C
    stops it cleanly."""
    proc = subprocess.Popen(
        [*CLI, "view", "--replay", str(trajectory_file), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=_env(),
    )
    try:
        url = None
        deadline = time.monotonic() + 120
        lines = []
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            match = re.search(r"open (http://127\.0\.0\.1:\d+)", line)
            if match:
                url = match.group(1)
        assert url, "no URL printed:\n" + "".join(lines)
        page = browser.new_page(url)
        try:
            page.wait_for_image(shows_both_teams, timeout=90)
        finally:
            page.close()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
