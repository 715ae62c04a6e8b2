"""How a Ctrl-C (SIGINT) or `kill` (SIGTERM) stops pe-mjx: one home for every part of it.

The handler never raises inside whatever code the signal lands in. It records the signal and
starts a watchdog; the long loops (between compiled calls, between pairings, trials, frames and
training iterations) call `check()`, which raises `KeyboardInterrupt` there, at a safe point, so
that the command unwinds (the viewer stops its server, training closes its loggers) and the
command line ends the process with `exit_now` (one line, exit 130, no interpreter teardown).

Raising from the handler itself was the old design, and a probe of `pe-mjx evaluate` (six
Ctrl-Cs, 2026-12-05) found both of its failures: a `KeyboardInterrupt` raised inside a jax
weakref or GC callback is printed as "Exception ignored ..." and dropped (the run went on to
its end, exit 0), and one that unwound through the interpreter's exit while XLA's threads were
still running died of SIGSEGV after "pe-mjx: interrupted".

* `on_interrupt`, installed by the command line (`install_for_cli`, as soon as `pe_mjx` is
  imported by the `pe-mjx` script, and `installed()` around every command), records the signal
  and arms the watchdog: a main thread that reaches no `check()` within `REACH_GRACE_S` (it is in
  a compile or in one long compiled call) is not waited for: the watchdog prints the one line and
  ends the process (exit 130). Every output is written to a temporary and renamed into place
  (`pe_mjx.outputs`), so ending there leaves nothing half-written. Once a `check()` has raised,
  the command has `INTERRUPT_GRACE_S` to unwind. faulthandler's C thread, which needs no GIL, is a
  last backstop for a main thread stuck in native code holding the GIL (every thread's stack on
  stderr for a bug report, exit 1). A second signal ends the process at once (unless a checkpoint
  is being saved).
* `deferred()` holds the signals back while a checkpoint is written, and replays the first one
  after it, so that a stop never lands inside an orbax save (`SAVE_GRACE_S` bounds a save that
  never ends); the watchdog waits for a save under way.
* `exit_now` ends the process without joining threads: orbax, jax or a logger may leave one that
  waits forever, and once the outputs are on disk nothing is lost by not waiting.

Outside the command line (the library in a notebook, `cli.main` called by tests) nothing of this
is installed unless `installed()` is entered, and `check()` does nothing while no signal came.

Standard library only, so that the command line imports it before anything heavy.
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

INTERRUPT_GRACE_S = 30.0
"""Seconds a command has, after a `check()` raised, to unwind (close its loggers, stop its
server)."""
REACH_GRACE_S = 2.0
"""Seconds the main thread has, after the signal, to reach a `check()` before the watchdog ends
the process itself (exit 130)."""
SAVE_GRACE_S = 120.0
"""Seconds a save may still take after a Ctrl-C held back for it (states here save in < 1 s)."""
MESSAGE = "pe-mjx: interrupted"
"""The one line a stopped command prints."""

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class _State:
    """What the handler recorded (one per process)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.raised_at: float | None = None
        """When a `check()` first raised (the unwinding began)."""
        self.saving = 0
        """How many `deferred()` blocks are open."""
        self.save_began: float | None = None
        self.watchdog: threading.Thread | None = None
        self.for_cli = False
        """Installed by the `pe-mjx` script: an interrupted command ends with `exit_now`."""
        self.finishing = False
        """The command completed (`finish`): a signal now ends the process at once."""


_state = _State()
_exit_lock = threading.Lock()
_temporaries: dict[int, Any] = {}
"""What `exit_now` removes before the process ends (`pe_mjx.outputs` registers the temporary
files and directories it is writing)."""


@contextlib.contextmanager
def removed_on_exit(remove: Any) -> Iterator[None]:
    """Within the block, `exit_now` calls `remove()` (best effort) before ending the process."""
    key = id(remove)
    _temporaries[key] = remove
    try:
        yield
    finally:
        _temporaries.pop(key, None)


def real_stderr() -> Any:
    """The process's own stderr (`sys.__stderr__`) where it is a file faulthandler can write to
    from C (not under pytest's capture, nor under pythonw); else None."""
    stream = sys.__stderr__
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):
        return None
    return stream


def exit_now(message: str, code: int) -> None:
    """Prints `message` on stderr and ends the process at once, joining no thread. Two threads
    that call it together (the watchdog and the main thread) print one line: the second waits
    for the first's exit."""
    _exit_lock.acquire()
    # Only from the main thread: removed under the feet of a main thread still running (the
    # watchdog's exit), a temporary would turn into an error line of its own. The watchdog's
    # leave theirs to the next write into that directory (`pe_mjx.outputs.clean_stale`).
    if threading.current_thread() is threading.main_thread():
        for remove in list(_temporaries.values()):
            with contextlib.suppress(Exception):
                remove()
    # The command line's line goes to the process's own stderr: the watchdog may end the process
    # while the main thread has `sys.stderr` redirected (the flag parse captures tyro's output),
    # and the line printed there was lost (exit 130 with nothing on stderr, a flaky CI test).
    stream = (real_stderr() if _state.for_cli else None) or sys.stderr
    with contextlib.suppress(OSError, ValueError):  # a closed stderr must not keep it alive
        print(message, file=stream, flush=True)
    with contextlib.suppress(OSError, ValueError):
        sys.stdout.flush()
    os._exit(code)


def _backstop(seconds: float) -> None:
    """Arms faulthandler's C watchdog: after `seconds`, every thread's stack and exit code 1."""
    if (stream := real_stderr()) is not None:
        faulthandler.dump_traceback_later(seconds, exit=True, file=stream)


def pending() -> int | None:
    """The signal recorded and not yet acted upon by the process's end (None: none came)."""
    return _state.signum


def check() -> None:
    """A safe point: raises `KeyboardInterrupt` if a SIGINT or SIGTERM came (every time it is
    called after one, so that a caller that swallowed it meets it again at the next one)."""
    if _state.signum is None:
        return
    if _state.raised_at is None:
        _state.raised_at = time.monotonic()
    raise KeyboardInterrupt


def sleep(seconds: float) -> None:
    """`time.sleep` in short steps with a `check()` after each (a wait loop's safe point)."""
    end = time.monotonic() + seconds
    while True:
        check()
        left = end - time.monotonic()
        if left <= 0:
            return
        time.sleep(min(left, 0.1))


def _watch(received: float) -> None:
    """The watchdog thread (see the module docstring)."""
    while True:
        time.sleep(0.05)
        now = time.monotonic()
        if _state.saving:
            began = _state.save_began or now
            if now - began < SAVE_GRACE_S:
                continue
            exit_now(f"{MESSAGE} (a checkpoint save did not end in {SAVE_GRACE_S:.0f} s)", 130)
        if _state.raised_at is not None:
            if now - _state.raised_at >= INTERRUPT_GRACE_S:
                exit_now(f"{MESSAGE} (ended after {INTERRUPT_GRACE_S:.0f} s of unwinding)", 130)
        elif now - received >= REACH_GRACE_S:
            exit_now(MESSAGE, 130)


def on_interrupt(signum: int, frame: object) -> None:
    """The SIGINT/SIGTERM handler of the command line: records the signal, never raises (see
    the module docstring)."""
    if _state.finishing:  # the command is done: nothing left to unwind
        exit_now(MESSAGE, 130)
    if _state.signum is not None:  # a second Ctrl-C: the user does not want to wait
        if _state.for_cli and not _state.saving:
            exit_now(MESSAGE, 130)
        return
    _state.signum = signum
    if not _state.for_cli:  # in-process (tests, notebooks): no watchdog ends the caller
        return
    watchdog = threading.Thread(
        target=_watch, args=(time.monotonic(),), name="pe-mjx-interrupt", daemon=True
    )
    _state.watchdog = watchdog
    watchdog.start()
    _backstop(SAVE_GRACE_S + INTERRUPT_GRACE_S + 15)


def _install() -> dict[int, Any]:
    return {sig: signal.signal(sig, on_interrupt) for sig in _SIGNALS}


def install_for_cli() -> None:
    """Installs `on_interrupt` for the rest of the process: the `pe-mjx` script does it as soon
    as it imports `pe_mjx` (a Ctrl-C during the imports, seconds long, is then one line too), also
    where the shell left SIGINT ignored (a background job of a non-interactive shell inherits
    that). An interrupted command then ends with `stop()`'s `exit_now`."""
    if threading.current_thread() is not threading.main_thread():
        return
    _state.for_cli = True
    _install()


def invoked_as_cli(argv0: str) -> bool:
    """Whether the process is the `pe-mjx` script (its `sys.argv[0]`)."""
    name = os.path.basename(argv0)
    return name in ("pe-mjx", "pe-mjx.exe")


def stop() -> None:
    """The end of an interrupted command: the one line and exit 130, without the interpreter's
    teardown when this is the `pe-mjx` process (XLA's threads may still run: tearing down under
    them crashed), else `SystemExit(130)` (`cli.main` called in-process, by tests)."""
    if _state.for_cli:
        exit_now(MESSAGE, 130)
    print(MESSAGE, file=sys.stderr, flush=True)
    _state.signum = None
    _state.raised_at = None
    raise SystemExit(130)


def handled() -> None:
    """Forgets the signal recorded: the command stopped on it as its normal end (the viewer's
    server, which Ctrl-C stops: exit 0)."""
    _state.signum = None
    _state.raised_at = None


def finish() -> None:
    """The end of a command that completed, in the `pe-mjx` process: the exit functions run (a
    signal during them ends the process at once, exit 130), then the process ends with exit 0
    without the interpreter's teardown, during which a Ctrl-C killed it (Python restores the
    default SIGINT action then: a signal death, not exit 130) and XLA's threads may still run.
    Elsewhere (`cli.main` called in-process) it does nothing."""
    if not _state.for_cli or threading.current_thread() is not threading.main_thread():
        return
    _state.finishing = True
    if _state.signum is not None:
        exit_now(MESSAGE, 130)
    import atexit

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    _exit_lock.acquire()
    os._exit(0)


@contextlib.contextmanager
def installed() -> Iterator[None]:
    """Within the block: `on_interrupt` handles SIGINT and SIGTERM (also where the shell left
    SIGINT ignored), and `kill -USR1 PID` writes every thread's stack to stderr while the process
    goes on (to see where a run that seems stuck waits). The previous handlers come back after
    it, so that `cli.main` called in-process (tests, notebooks) leaves its caller's signals as
    they were."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = _install()
    stream = real_stderr()
    if stream is not None:
        faulthandler.register(signal.SIGUSR1, file=stream, all_threads=True)
    try:
        yield
    finally:
        if stream is not None:
            faulthandler.unregister(signal.SIGUSR1)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if not _state.for_cli:  # in-process: the next command starts afresh
            _state.signum = None
            _state.raised_at = None
            faulthandler.cancel_dump_traceback_later()


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Holds SIGINT and SIGTERM back until the block is done, then does what the first one
    would have done (the installed handler, then `KeyboardInterrupt`; an ignored one stays
    ignored). A signal recorded before the block (`on_interrupt`) raises after it too.

    A Ctrl-C that landed inside an orbax save raised in the main thread while orbax's worker
    threads were midway; they then waited forever for the main thread, and the process hung
    instead of exiting (a flaky CI test, 2026-12). Deferred, the save finishes (well under a
    second for this project's states) and the stop comes after it, with that checkpoint complete;
    the watchdog waits while a save is under way. Should the save still run `SAVE_GRACE_S` after
    it began, the watchdog (or the faulthandler backstop) ends the process; the checkpoints
    completed before stay intact (orbax commits a step by renaming it into place). Outside the
    main thread signals cannot be handled and nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []

    def hold(num: int, _frame: object) -> None:
        if not caught and _state.signum is None:  # a save that never ends
            _backstop(SAVE_GRACE_S)  # must not hold the stop back forever
        caught.append(num)

    previous = {sig: signal.signal(sig, hold) for sig in _SIGNALS}
    _state.saving += 1
    if _state.saving == 1:
        _state.save_began = time.monotonic()
    try:
        yield
    finally:
        _state.saving -= 1
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if caught:
        if _state.signum is None:
            faulthandler.cancel_dump_traceback_later()
        handler = previous[caught[0]]
        if handler == signal.SIG_IGN:
            return
        if callable(handler):  # the command line's handler, or Python's default_int_handler
            handler(caught[0], None)
        check()  # `on_interrupt` recorded it: the unwinding begins here
        raise KeyboardInterrupt  # SIG_DFL
    check()


__all__ = [
    "INTERRUPT_GRACE_S",
    "MESSAGE",
    "REACH_GRACE_S",
    "SAVE_GRACE_S",
    "check",
    "deferred",
    "exit_now",
    "finish",
    "handled",
    "install_for_cli",
    "installed",
    "invoked_as_cli",
    "on_interrupt",
    "pending",
    "real_stderr",
    "removed_on_exit",
    "sleep",
    "stop",
]
