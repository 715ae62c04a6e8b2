"""pe_mjx/interrupts.py: Ctrl-C and `kill` held back around atomic work, then raised."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pe_mjx import interrupts
from pe_mjx.interrupts import deferred

CLI = str(Path(sys.executable).parent / "pe-mjx")


def test_an_interrupt_during_a_save_waits_for_the_save_then_stops_the_run():
    """Ctrl-C inside a save is held back (orbax's threads hung when it landed midway) and raised
    as KeyboardInterrupt once the block is done; the handlers are restored after."""
    # Python's own handler, whatever ran before in this process (the replay goes through it).
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        finished = False
        with pytest.raises(KeyboardInterrupt), deferred():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGTERM)
            finished = True  # reached: the signals did not interrupt the block
        assert finished
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        with deferred():  # no signal: nothing raised
            pass
    finally:
        signal.signal(signal.SIGINT, outer)


def test_the_handler_records_and_never_raises_the_safe_points_raise():
    """A KeyboardInterrupt raised by the handler inside a jax weakref or GC callback was printed
    as "Exception ignored" and dropped (the run went on to exit 0): the handler only records,
    and `check()` raises at a safe point, every time until the command ends."""
    outer = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with interrupts.installed():
        interrupts.check()  # no signal: nothing
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler has run by now, and raised nothing
        assert interrupts.pending() == signal.SIGINT
        for _ in range(2):
            with pytest.raises(KeyboardInterrupt):
                interrupts.check()
        with pytest.raises(KeyboardInterrupt), deferred():  # a save: done, then the stop
            saved = True
        assert saved
    assert interrupts.pending() is None  # in-process: the next command starts afresh
    assert {s: signal.getsignal(s) for s in outer} == outer


def test_the_line_reaches_the_real_stderr_while_a_redirect_is_in_flight():
    """A Ctrl-C during the flag parse, which captures stderr to turn tyro's output into one line,
    was ended by the watchdog with its line printed into the capture: exit 130 and an empty
    stderr (a CI failure). The line goes to the process's own stderr."""
    code = (
        "import contextlib, io, os, signal, time\n"
        "from pe_mjx import interrupts\n"
        "interrupts.install_for_cli()\n"
        "with contextlib.redirect_stderr(io.StringIO()):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(30)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip().splitlines() == [interrupts.MESSAGE]


def _tiny_evaluate(out: Path) -> list[str]:
    return [
        CLI, "evaluate", "--pursuers", "scripted", "--evaders", "scripted", "--preset", "4-1-2",
        "--backend", "kinematic", "--trials", "4", "--record", "1", "--no-progress",
        "--out", str(out),
    ]  # fmt: skip


def _wait_for(proc: subprocess.Popen, err_path: Path, marker: str | None) -> None:
    """Until `marker` shows on the command's stderr (None: one second); the command must still
    be running then, or the test says where it got to."""
    deadline = time.monotonic() + (1.0 if marker is None else 300.0)
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"ended before {marker!r}: {err_path.read_text()[-2000:]}"
        if marker is not None and marker in err_path.read_text():
            return
        time.sleep(0.02)
    assert marker is None, f"no {marker!r} within 300 s: {err_path.read_text()[-2000:]}"


# Where the signal lands: the imports (1 s in), the game's compile, and the recording (the
# trials are played by then). Each is awaited on stderr, not guessed from a delay, so no run of
# the test can miss its phase.
PHASES = [None, ": compiling...", "compiling the recording..."]


@pytest.mark.parametrize("marker", PHASES, ids=["imports", "compile", "recording"])
def test_ctrl_c_into_evaluate_ends_it_with_one_line_and_exit_130(tmp_path, marker):
    """At any time (the imports, the compile, the trials): exit 130 within seconds, the one line
    "pe-mjx: interrupted" and nothing else on stderr after it, no traceback (a probe found 3 of 6
    SIGSEGV after the line: the interpreter tore down under XLA's threads), and --out absent or
    whole. `tools/stress_tests.py interrupts` does this 20 times at random times."""
    out = tmp_path / "res"
    err_path = tmp_path / "stderr.txt"
    with open(err_path, "w") as err:
        proc = subprocess.Popen(
            _tiny_evaluate(out), stdout=subprocess.DEVNULL, stderr=err, start_new_session=True
        )
    try:
        _wait_for(proc, err_path, marker)
        proc.send_signal(signal.SIGINT)
        tic = time.monotonic()
        code = proc.wait(timeout=60)
        seconds = time.monotonic() - tic
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = err_path.read_text()
    assert code == 130, stderr[-3000:]
    assert seconds < 15, seconds
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines[-1] == "pe-mjx: interrupted", stderr[-3000:]
    assert sum(line.startswith("pe-mjx: interrupted") for line in lines) == 1
    for bad in ("Traceback", "Fatal Python error", "Exception ignored"):
        assert bad not in stderr, stderr[-3000:]
    if out.exists():
        assert (out / "results.json").is_file() and (out / "results.md").is_file()
    # A temporary the watchdog's exit left (it never removes one under a running main thread)
    # goes with the next write there.
    from pe_mjx import outputs

    outputs.write_file(tmp_path / "next.txt", "x")
    assert not [p.name for p in tmp_path.iterdir() if outputs.TEMP_MARK in p.name]
