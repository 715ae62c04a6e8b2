"""pe_mjx/policy/quiet.py: a damaged checkpoint's read is reported once, other reports pass."""

from __future__ import annotations

import asyncio
import logging
import sys
from types import SimpleNamespace

import pytest
import uvloop

from pe_mjx.policy import quiet


def test_late_echoes_of_a_failed_array_read_are_dropped_and_nothing_else(monkeypatch):
    """Orbax's unawaited reads of a damaged checkpoint report their failures when collected,
    long after the one error line; only those echoes are dropped, at the hook and the log."""
    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_value))
    with quiet.quiet_logs():
        pass
    echo = Exception("Encountered error while reading array index: TensorStore({...})")
    chained = ValueError("restore failed")
    chained.__cause__ = ValueError('OUT_OF_RANGE: Error reading "l00016/0.0" in OCDBT database')
    other = RuntimeError("a user's own failure")
    for exc in (echo, chained, other):
        sys.unraisablehook(SimpleNamespace(exc_value=exc, exc_traceback=None, object=None))
    assert seen == [other]

    # A read still in flight posts to orbax's closed loop from native code: dropped only once a
    # checkpoint read of this process has failed. Orbax's loop is uvloop's (one of its
    # requirements on Linux), asyncio's where uvloop is missing.
    for new_loop in (uvloop.new_event_loop, asyncio.new_event_loop):
        loop = new_loop()
        loop.close()
        try:
            loop.call_soon_threadsafe(print)
        except RuntimeError as err:
            tb = err.__traceback__.tb_next  # from the loop's frame on, as from native code
            late = SimpleNamespace(exc_value=err, exc_traceback=tb, object=None)
        monkeypatch.setattr(quiet, "_READS_FAILED", False)
        sys.unraisablehook(late)
        assert seen[-1] is late.exc_value
        with pytest.raises(ValueError), quiet.quiet_logs():
            raise ValueError("a damaged array")
        sys.unraisablehook(late)
        assert seen[-1] is late.exc_value and len(seen) == 2
        seen.pop()

    log = logging.getLogger("asyncio")
    records = [
        logging.LogRecord("asyncio", logging.ERROR, __file__, 1, "never retrieved", (), info)
        for info in ((type(e), e, None) for e in (echo, chained, other))
    ]
    assert [r.exc_info[1] for r in records if log.filter(r)] == [other]
