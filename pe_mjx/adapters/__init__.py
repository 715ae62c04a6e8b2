"""Adapters to other multi-agent APIs: PettingZoo `ParallelEnv` and JaxMARL `MultiAgentEnv`.

Each lives in its own module and imports its library only there, so `pe_mjx` stays importable
without them (install with `pip install pe-mjx[pettingzoo]` or `pe-mjx[jaxmarl]`):

    from pe_mjx.adapters.pettingzoo import PettingZooEnv
    from pe_mjx.adapters.jaxmarl import JaxMARLEnv
"""

from pe_mjx.adapters.common import (
    OBSERVATION_KEYS,
    agent_names,
    flatten_observation,
    observation_layout,
)

__all__ = ["OBSERVATION_KEYS", "agent_names", "flatten_observation", "observation_layout"]
