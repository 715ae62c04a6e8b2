"""The Viser web viewer: live arenas, replays, recordings and MIX attention (`pe-mjx view`)."""

from pe_mjx.viewer.app import Viewer, ViewerOptions, start_viewer

__all__ = ["Viewer", "ViewerOptions", "start_viewer"]
