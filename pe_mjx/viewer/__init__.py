"""The Viser web viewer: live arenas, replays, recordings and MIX attention (`pe-mjx view`).

The app (and with it JAX and viser) is imported on first use, so that `pe-mjx view` can check its
flags (`pe_mjx.viewer.guard`) and fail in a second.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Viewer", "ViewerOptions", "start_viewer"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from pe_mjx.viewer import app

        return getattr(app, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
