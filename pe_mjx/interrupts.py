"""How a Ctrl-C (SIGINT) or `kill` (SIGTERM) stops pe-mjx: one home for every part of it.

* `on_interrupt`, installed by the command line, raises `KeyboardInterrupt`, so that every command
  unwinds as it does on Ctrl-C (the viewer stops its server, training closes its loggers), and
  arms two watchdogs: a Python timer that ends the process after `INTERRUPT_GRACE_S` of unwinding
  (exit 130), and faulthandler's C thread, which needs no GIL, 15 s later (every thread's stack on
  stderr for a bug report, exit 1), for a main thread stuck in native code.
* `deferred()` holds the signals back while a checkpoint is written, and replays the first one
  after it, so that a stop never lands inside an orbax save (`SAVE_GRACE_S` bounds a save that
  never ends).
* `exit_now` ends the process without joining threads: orbax, jax or a logger may leave one that
  waits forever, and once the checkpoints are on disk nothing is lost by not waiting.

Under a loaded machine one Ctrl-C'd training run in 20 did not end within 120 s (2026-12-02,
`tools/stress_tests.py`) although its checkpoints were complete; with the watchdogs every run of
the stress ends (docs/benchmarks.md, "Ctrl-C").

Standard library only, so that the command line imports it before anything heavy.
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

INTERRUPT_GRACE_S = 30.0
"""Seconds a command has, after Ctrl-C, to unwind (close its loggers, stop its server)."""
SAVE_GRACE_S = 120.0
"""Seconds a save may still take after a Ctrl-C held back for it (states here save in < 1 s)."""


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
    """Prints `message` on stderr and ends the process at once, joining no thread."""
    print(message, file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(code)


def _backstop(seconds: float) -> None:
    """Arms faulthandler's C watchdog: after `seconds`, every thread's stack and exit code 1."""
    if (stream := real_stderr()) is not None:
        faulthandler.dump_traceback_later(seconds, exit=True, file=stream)


def on_interrupt(signum: int, frame: object) -> None:
    """The SIGINT/SIGTERM handler of the command line (see the module docstring)."""
    message = f"pe-mjx: interrupted (ended after {INTERRUPT_GRACE_S:.0f} s of unwinding)"
    watchdog = threading.Timer(INTERRUPT_GRACE_S, exit_now, args=(message, 130))
    watchdog.daemon = True
    watchdog.start()
    _backstop(INTERRUPT_GRACE_S + 15)
    raise KeyboardInterrupt


@contextlib.contextmanager
def installed() -> Iterator[None]:
    """Within the block: `on_interrupt` handles SIGINT and SIGTERM (also where the shell left
    SIGINT ignored, as a background job of a non-interactive shell inherits it), and `kill -USR1
    PID` writes every thread's stack to stderr while the process goes on (to see where a run
    that seems stuck waits). The previous handlers come back after it, so that `cli.main` called
    in-process (tests, notebooks) leaves its caller's signals as they were."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, on_interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
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


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Holds SIGINT and SIGTERM back until the block is done, then does what the first one
    would have done (the installed handler, or `KeyboardInterrupt`; an ignored one stays ignored).

    A Ctrl-C that landed inside an orbax save raised in the main thread while orbax's worker
    threads were midway; they then waited forever for the main thread, and the process hung
    instead of exiting (a flaky CI test, 2026-12). Deferred, the save finishes (well under a
    second for this project's states) and the stop comes after it, with that checkpoint complete.
    Should the save still run `SAVE_GRACE_S` after the signal, the faulthandler backstop ends the
    process; the checkpoints completed before stay intact (orbax commits a step by renaming it
    into place). Outside the main thread signals cannot be handled and nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []

    def hold(num: int, _frame: object) -> None:
        if not caught:  # a save that never ends must not hold the stop back forever
            _backstop(SAVE_GRACE_S)
        caught.append(num)

    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.signal(sig, hold) for sig in signals}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if caught:
        faulthandler.cancel_dump_traceback_later()
        handler = previous[caught[0]]
        if handler == signal.SIG_IGN:
            return
        if callable(handler):  # the command line's handler, or Python's default_int_handler
            handler(caught[0], None)
        raise KeyboardInterrupt  # SIG_DFL, or a handler that did not raise


__all__ = [
    "INTERRUPT_GRACE_S",
    "SAVE_GRACE_S",
    "deferred",
    "exit_now",
    "installed",
    "on_interrupt",
    "real_stderr",
]
