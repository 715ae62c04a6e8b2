"""`pe-mjx view` for real, through a subprocess: flags, errors, export, the served page."""

from __future__ import annotations

import concurrent.futures
import os
import re
import signal
import subprocess
import sys
import time
import zipfile

import pytest

from pe_mjx.trajectory import save
from tests.viewer.browser import shows_both_teams
from tests.viewer.viewer_helpers import synthetic_trajectory

CLI = [sys.executable, "-m", "pe_mjx.cli"]


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*CLI, *args], capture_output=True, text=True, timeout=timeout, env=_env()
    )


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONFAULTHANDLER"] = "1"
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


@pytest.fixture(scope="module")
def bad_inputs(tmp_path_factory, trajectory_file):
    """Damaged files and paths for the bad-argument table."""
    root = tmp_path_factory.mktemp("bad")
    # A 12 KB replay whose poses header claims 3.27 TiB.
    with zipfile.ZipFile(trajectory_file) as src, zipfile.ZipFile(root / "huge.npz", "w") as dst:
        for info in src.infolist():
            if info.filename != "poses.npy":
                dst.writestr(info.filename, src.read(info))
        header = repr({"descr": "<f4", "fortran_order": False, "shape": (10**6, 10**5, 3, 3)})
        header = header.encode() + b" " * (63 - (len(header) + 10) % 64) + b"\n"
        npy = b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header
        dst.writestr("poses.npy", npy + b"\0" * 12_000, zipfile.ZIP_STORED)
    (root / "damaged-run" / "checkpoints" / "3").mkdir(parents=True)
    (root / "damaged-run" / "checkpoints" / "3" / "_CHECKPOINT_METADATA").write_text("{not json")
    (root / "damaged-run" / "config.json").write_text('{"preset": 7')
    (root / "a-file").write_text("")
    return root


def bad_view_arguments(bad) -> list[tuple[tuple[str, ...], str]]:
    """(arguments of `pe-mjx view`, what its one error line must say)."""
    return [
        (("--preset", "nope"), "invalid choice 'nope'"),
        (("--replay", "/no/such/file.npz"), "no such file"),
        (("--replay", str(bad)), "not a file"),
        (("--replay", str(bad / "huge.npz")), "huge.npz: poses declares 3,600,000,000,000 bytes"),
        (("--arenas", "0"), "--arenas must be in 1..64, got 0"),
        (("--arenas", "65"), "--arenas must be in 1..64, got 65"),
        (("--backend", "warp"), "invalid choice 'warp'"),
        (("--port", "-1"), "--port must be in 0..65535, got -1"),
        (("--port", "70000"), "--port must be in 0..65535, got 70000"),
        (("--host", "no-such-host.invalid"), "--host 'no-such-host.invalid' does not resolve"),
        (("--host", "192.0.2.1"), "--host '192.0.2.1': cannot listen on 192.0.2.1"),
        (("--seed", "-1"), "--seed must be in 0..4294967295, got -1"),
        (("--seed", str(2**63)), "--seed must be in 0..4294967295"),
        (("--speed", "nan"), "--speed must be a finite number >= 0, got nan"),
        (("--speed", "-1"), "--speed must be a finite number >= 0"),
        (("--steps", "0", "--export", str(bad / "x")), "--steps must be >= 1"),
        (("--record-dir", str(bad / "a-file")), "--record-dir: "),
        (("--policy-roots", str(bad / "none")), "--policy-roots: "),
        (("--pursuers", "nope", "--preset", "2-1-1"), "--pursuers: pursuer policy 'nope'"),
        (("--pursuers", str(bad / "damaged-run"), "--preset", "2-1-1"), "--pursuers: "),
        (("--evaders", str(bad / "a-file"), "--preset", "2-1-1"), "--evaders: "),
    ]


def test_bad_arguments_fail_fast_with_one_clear_error(bad_inputs):
    """Every bad flag or file: exit 2 within a minute (no hang), one `pe-mjx: error:` line that
    says what is wrong, no traceback, before any server starts."""
    cases = bad_view_arguments(bad_inputs)

    def attempt(args: tuple[str, ...]) -> subprocess.CompletedProcess:
        try:
            return run("view", *args, timeout=60)
        except subprocess.TimeoutExpired as err:
            return subprocess.CompletedProcess(err.cmd, -1, "", f"hung: {err}")

    with concurrent.futures.ThreadPoolExecutor(3) as pool:
        results = list(pool.map(attempt, [a for a, _ in cases]))
    failures = []
    for (args, message), out in zip(cases, results, strict=True):
        errors = [line for line in out.stderr.splitlines() if line.startswith("pe-mjx: error:")]
        last = (out.stderr.strip().splitlines() or [""])[-1]
        clear = out.returncode == 2 and len(errors) == 1 and errors[0] == last
        if not (clear and message in last and "Traceback" not in out.stderr):
            failures.append(f"{' '.join(args)}: exit {out.returncode}\n{out.stderr[-600:]}")
    print(f"pe-mjx view: {len(cases)} bad invocations, {len(cases) - len(failures)} clear errors")
    assert not failures, "\n\n".join(failures)


def test_non_local_host_prints_a_warning(trajectory_file):
    proc = subprocess.Popen(
        [*CLI, "view", "--replay", str(trajectory_file), "--host", "0.0.0.0", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=_env(),
    )
    try:
        lines = []
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line or "open http://" in line:
                break
            lines.append(line)
        text = "".join(lines)
        assert "pe-mjx view: warning: --host 0.0.0.0 serves the viewer to other machines" in text
        proc.send_signal(signal.SIGINT)
        try:  # communicate drains the output, so a full pipe cannot block the child's exit
            rest, _ = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)  # PYTHONFAULTHANDLER: every thread's stack
            rest, _ = proc.communicate(timeout=30)
            raise AssertionError(f"no exit 60 s after Ctrl-C; its threads:\n{rest}") from None
        assert proc.returncode in (0, 130), rest  # 130: the Ctrl-C came before the wait loop
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


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
