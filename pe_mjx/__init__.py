"""pe-mjx: large-scale multi-agent pursuit-evasion under collision avoidance in MuJoCo MJX."""

import sys as _sys

from pe_mjx import interrupts as _interrupts

if _sys.argv and _interrupts.invoked_as_cli(_sys.argv[0]):
    # The `pe-mjx` script: a Ctrl-C during the imports below (seconds long) is one line too.
    _interrupts.install_for_cli()

from pe_mjx import _quiet  # noqa: F401  (first heavy import: silences mjx's print)
from pe_mjx.config import (
    PRESETS,
    ArenaConfig,
    EnvConfig,
    RewardConfig,
    TeamConfig,
    get_preset,
)
from pe_mjx.env import AutoResetWrapper, PursuitEvasionEnv, State, World, make

__all__ = [
    "PRESETS",
    "ArenaConfig",
    "AutoResetWrapper",
    "EnvConfig",
    "PursuitEvasionEnv",
    "RewardConfig",
    "State",
    "TeamConfig",
    "World",
    "get_preset",
    "load_policy",
    "make",
]


def __getattr__(name: str):
    # Lazy: the training stack (flax, optax, orbax, brax) loads only when a policy is loaded.
    if name == "load_policy":
        from pe_mjx.policy.resolve import load_policy

        return load_policy
    raise AttributeError(f"module 'pe_mjx' has no attribute {name!r}")
