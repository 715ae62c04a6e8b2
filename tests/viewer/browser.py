"""The viewer tests' browser: `pe_mjx.viewer.browser`'s Playwright driver, plus the pytest glue.

The driver itself (`Browser`, `Page`, `scene_region`, `team_pixels`, ...) lives in
`pe_mjx/viewer/browser.py`, because the soak and the benchmark use it too and a tool must not
import a test; this module re-exports it for the tests and adds `require_chromium`
(pytest's skip/fail).
"""

from __future__ import annotations

import os

from pe_mjx.viewer.browser import (
    ACTION_TIMEOUT_MS,
    CHROMIUM_ARGS,
    LIVE_VIEWER,
    Browser,
    BrowserError,
    ConnectionProxy,
    Page,
    find_chromium,
    scene_region,
    shows_both_teams,
    team_counts,
    team_pixels,
)


def require_chromium() -> str:
    """For tests: the Chromium path; skips without one (or without Playwright), but fails under
    CI=true (the browser tests must run in CI)."""
    import importlib.util

    import pytest

    path = find_chromium()
    missing = None
    if path is None:
        missing = "no Chromium was found (apt-get install chromium, or set $CHROMIUM)"
    elif importlib.util.find_spec("playwright") is None:
        missing = "Playwright is not installed (pip install -e '.[dev]')"
    if missing is not None:
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(
                f"CI is set but {missing}: the viewer's browser tests must run "
                "(.ci/run installs Debian's chromium)"
            )
        pytest.skip(f"{missing}: the viewer's browser tests need it")
    return path


__all__ = [
    "ACTION_TIMEOUT_MS",
    "CHROMIUM_ARGS",
    "LIVE_VIEWER",
    "Browser",
    "BrowserError",
    "ConnectionProxy",
    "Page",
    "find_chromium",
    "require_chromium",
    "scene_region",
    "shows_both_teams",
    "team_counts",
    "team_pixels",
]
