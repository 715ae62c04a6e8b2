"""pe-mjx: large-scale multi-agent pursuit-evasion under collision avoidance in MuJoCo MJX."""

from pe_mjx import _quiet  # noqa: F401  (first: silences mjx's import-time print)
from pe_mjx.config import PRESETS, ArenaConfig, EnvConfig, RewardConfig, TeamConfig, get_preset
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
