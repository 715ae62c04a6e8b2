"""Imports `mujoco.mjx` without its stray stdout (run first by `pe_mjx/__init__.py`)."""

from __future__ import annotations

import contextlib
import io
import sys


def import_mjx_quietly() -> None:
    """Imports `mujoco.mjx`, which prints "Failed to import warp: No module named 'warp'" (and
    the same for mujoco_warp) on stdout when the optional warp-lang is absent (SPEC 7). Those
    two lines are dropped so that `pe-mjx evaluate > table.md` captures only the table; any other
    output of the import (warp installed but broken, ...) goes to stderr; errors propagate."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stdout(captured):
            import mujoco.mjx  # noqa: F401
    finally:
        for line in captured.getvalue().splitlines():
            harmless = line.startswith(("Failed to import warp:", "Failed to import mujoco_warp:"))
            if not (harmless and line.endswith("No module named 'warp'")):
                print(line, file=sys.stderr)


import_mjx_quietly()
