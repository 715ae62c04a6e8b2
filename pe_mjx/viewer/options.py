"""What the viewer starts with: one typed config, which `pe-mjx view` takes as its flags."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from pe_mjx.config import PresetName
from pe_mjx.experiment import Backend

HOLD_SECONDS = 1.5
"""How long the last frame of a finished episode stays on screen before the next one starts."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class ViewerOptions:
    """Everything the viewer starts with (`start_viewer(options)`; each field is a `pe-mjx view`
    flag)."""

    preset: PresetName = "20-5-8"
    """Scenario preset (P-E-K); entity counts can be changed in the GUI."""
    pursuers: str = "scripted"
    """Pursuer policy: "scripted", "random", a shipped policy ("mix-20-5-8") or a `pe-mjx
    train` run directory."""
    evaders: str = "scripted"
    """Evader policy: "scripted", "random", a shipped policy ("mix-20-5-8") or a `pe-mjx
    train` run directory."""
    arenas: int | None = None
    """Arenas shown side by side in a grid (default 1; for a replay the file's first arenas,
    at most 16)."""
    backend: Backend = "mjx"
    """Env backend: "mjx" or "kinematic" (exact arcs, compiles and runs faster)."""
    seed: int = 0
    """Seed of the arenas' draws and the policies' sampling."""
    speed: float = 10.0
    """Env steps per second (0: as fast as possible)."""
    trails: bool = True
    """Draw each robot's recent path."""
    trail_length: int = 30
    """Steps of path a trail shows."""
    deterministic: bool = False
    """Learned policies play their most likely action instead of sampling."""
    loop: bool = True
    """Start new episodes when every arena is done (replays restart from frame 0)."""
    hold: float = HOLD_SECONDS
    """Seconds the last frame of a finished episode stays on screen before the next one."""
    play: bool = True
    """Start playing at once (else paused until Play is pressed)."""
    host: str = "127.0.0.1"
    """Address to bind; the default serves this machine only (any other prints a warning: every
    browser that reaches the page can control the viewer)."""
    port: int = 8080
    """Port (the next free one is used if it is taken)."""
    record_dir: Path = Path("recordings")
    """Where the GUI's recordings are written."""
    verbose: bool = True
    """Print the viewer's status lines and client connections."""
    policy_roots: tuple[Path, ...] | None = None
    """Directories under which policy runs typed into the page may be opened (default: the
    working directory and the shipped assets/policies). --pursuers/--evaders are always allowed."""


__all__ = ["HOLD_SECONDS", "ViewerOptions"]
