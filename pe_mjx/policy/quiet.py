"""Reading a checkpoint quietly: one error for a damaged file, not pages of library output.

Orbax reads a checkpoint's arrays concurrently on its own asyncio loop, through tensorstore.
When one array of a damaged checkpoint fails, the reader sees one exception, which the store
turns into one `CheckpointError` line; but orbax and tensorstore report the same failure many
more times, through their loggers while reading and, later, through the reads it abandoned.
`quiet_logs` silences the first and drops the second, and nothing else.
"""

from __future__ import annotations

import contextlib
import logging
import re
import sys
from collections.abc import Iterator
from typing import Any

_LIBRARY_DIRS = re.compile(r"[/\\](orbax|tensorstore)[/\\]")


def _from_array_read(exc: BaseException | None) -> bool:
    """Whether `exc`, or an exception it chains to, was raised by orbax or tensorstore while
    reading an array (tensorstore's own errors carry no Python frames, only their message)."""
    for _ in range(8):
        if exc is None:
            return False
        if any(word in str(exc)[:400] for word in ("TensorStore", "OCDBT")):
            return True
        tb = exc.__traceback__
        while tb is not None:
            if _LIBRARY_DIRS.search(tb.tb_frame.f_code.co_filename):
                return True
            tb = tb.tb_next
        exc = exc.__cause__ or exc.__context__
    return False


class _DropArrayReadEchoes(logging.Filter):
    """Drops asyncio's "exception was never retrieved" records of failed array reads."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not (record.exc_info and _from_array_read(record.exc_info[1]))


_READS_FAILED = False  # whether a checkpoint read in this process failed (`quiet_logs`)


def _late_post_to_closed_loop(unraisable: Any) -> bool:
    """A native callback (no Python caller) posting to an asyncio loop that was closed: orbax's
    loop is uvloop's where installed (its frame is `uvloop.loop.Loop.call_soon_threadsafe`),
    asyncio's otherwise (`call_soon_threadsafe`)."""
    exc, tb = unraisable.exc_value, unraisable.exc_traceback
    return (
        unraisable.object is None
        and isinstance(exc, RuntimeError)
        and str(exc) == "Event loop is closed"
        and tb is not None
        and tb.tb_frame.f_code.co_name.rsplit(".", 1)[-1] == "call_soon_threadsafe"
    )


def _drop_array_read_echoes() -> None:
    """Once per process: when one array of a damaged checkpoint fails to read, orbax leaves its
    other reads' coroutines and futures unawaited, and they report their own failures whenever
    the garbage collector reaches them (often at exit, after the one error line), as thousands
    of lines of tensorstore specs; reads still in flight then post their results to orbax's
    event loop, closed by then ("Event loop is closed", from native code). Those echoes of the
    one reported error are dropped, from `sys.unraisablehook` and asyncio's log alike; every
    other report passes through."""
    log = logging.getLogger("asyncio")
    if not any(isinstance(f, _DropArrayReadEchoes) for f in log.filters):
        log.addFilter(_DropArrayReadEchoes())
    if getattr(sys.unraisablehook, "_pe_mjx", False):
        return
    previous = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        code = getattr(unraisable.object, "cr_code", None)
        if (
            _from_array_read(unraisable.exc_value)
            or (code is not None and _LIBRARY_DIRS.search(code.co_filename))
            or (_READS_FAILED and _late_post_to_closed_loop(unraisable))
        ):
            return
        previous(unraisable)

    hook._pe_mjx = True  # type: ignore[attr-defined]
    sys.unraisablehook = hook


@contextlib.contextmanager
def quiet_logs() -> Iterator[None]:
    """Silences orbax's and absl's logging while a checkpoint is read, and the late echoes of a
    failed read (`_drop_array_read_echoes`): a damaged file is reported as one
    `CheckpointError`, not followed by pages of library tracebacks."""
    _drop_array_read_echoes()
    loggers = [logging.getLogger(name) for name in ("absl", "orbax", "tensorstore")]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    except Exception:
        global _READS_FAILED
        _READS_FAILED = True
        raise
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


__all__ = ["quiet_logs"]
