"""pe-mjx: large-scale multi-agent pursuit-evasion under collision avoidance in MuJoCo MJX."""

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
    "make",
]
