"""The game's names and sizes, in one place: teams, backends, encoders, features, causes, terms.

Pure Python (no jax, no numpy), at the bottom of the layer table (`tests/test_layout.py`): every
other module takes these from here instead of restating them.
"""

from __future__ import annotations

TEAMS = ("pursuer", "evader")
"""Team names, pursuers first (the order of agents in `World` and of every per-team loop)."""

BACKENDS = ("mjx", "kinematic")
"""Physics backends of `PursuitEvasionEnv`."""

ENCODERS = ("mix", "mean", "birnn", "mlp")
"""Network encoders: the paper's Mix-Attention and its three baselines."""

BUILTIN_POLICIES = ("scripted", "random")
"""Policy specs that need no checkpoint (`pe_mjx.policy.scripted.POLICIES`)."""

POLICY_NAME = r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}"
"""The pattern (for `re.fullmatch`) of a shipped policy's name and of the sibling a packed
policy shares parameters with: letters, digits, `.`, `_` and `-`, no separators
(`pe_mjx.policy.ship`, `pe_mjx.policy.packed`)."""

PARK_DISTANCE = 10.0
"""Absent agents and obstacles wait this many arena radii from the centre, one metre apart: far
beyond every distance a rule looks at (collisions, rewards, action masks), and masked out of
every observation (`pe_mjx.stages.placement`)."""

# Observation layout (SPEC 2.5): one feature vector per entity, per observing agent.
OWN_FEATURES = 5
AGENT_FEATURES = 6
OBSTACLE_FEATURES = 4
ENTITY_KEYS = ("own", "teammates", "opponents", "obstacles")
"""The entity blocks of a team's observation dict, in their flattening order."""
ENTITY_TYPES = ENTITY_KEYS[1:]
FEATURES = {
    "own": OWN_FEATURES,
    "teammates": AGENT_FEATURES,
    "opponents": AGENT_FEATURES,
    "obstacles": OBSTACLE_FEATURES,
}
"""Features per entity of each block."""
LENGTH_FEATURES = {"teammates": (1,), "opponents": (1,), "obstacles": (0, 3)}
"""Per block, the features that are lengths relative to the observer's neighbours (distance;
an obstacle's radius), in arena radii: what `NetworkConfig.length_unit` puts in metres."""
MASK_KEYS = {
    "teammates": "teammate_mask",
    "opponents": "opponent_mask",
    "obstacles": "obstacle_mask",
}
"""The validity mask of each entity block."""
OBSERVATION_KEYS = (*ENTITY_KEYS, *MASK_KEYS.values(), "action_mask")
"""Every key of a team's observation dict, in their canonical (flattening) order."""

# Incapacitation causes (`World.cause`); 0 means still active.
ACTIVE, WALL, OBSTACLE, CAPTURE, TEAMMATE, OPPONENT = range(6)
NUM_CAUSES = 6
CAUSE_NAMES = {
    WALL: "wall",
    OBSTACLE: "obstacle",
    CAPTURE: "capture",
    TEAMMATE: "teammate",
    OPPONENT: "opponent",
}
"""Cause code -> name, for the codes of incapacitated agents."""
ABSENT = -1
"""`World.cause` of an agent left out of the episode (`TeamConfig.min_agents`): it is inactive
from the start, and no cause, outcome or observation counts it."""

# Reward terms (eqs. (3) and (4)), each logged as `reward/<team>/<term>`.
PURSUER_TERMS = ("wall", "obstacle", "teammate", "pursuit", "capture", "opponent")
EVADER_TERMS = ("wall", "obstacle", "teammate", "opponent", "alive", "flee")
REWARD_TERMS = {"pursuer": PURSUER_TERMS, "evader": EVADER_TERMS}


def other_team(team: str) -> str:
    """The opposing team's name."""
    if team not in TEAMS:
        raise ValueError(f"unknown team {team!r}; expected one of {TEAMS}")
    return TEAMS[1 - TEAMS.index(team)]


__all__ = [
    "ABSENT",
    "ACTIVE",
    "AGENT_FEATURES",
    "BACKENDS",
    "BUILTIN_POLICIES",
    "CAPTURE",
    "CAUSE_NAMES",
    "ENCODERS",
    "ENTITY_KEYS",
    "ENTITY_TYPES",
    "EVADER_TERMS",
    "FEATURES",
    "LENGTH_FEATURES",
    "MASK_KEYS",
    "NUM_CAUSES",
    "OBSERVATION_KEYS",
    "OBSTACLE",
    "OBSTACLE_FEATURES",
    "OPPONENT",
    "OWN_FEATURES",
    "PARK_DISTANCE",
    "PURSUER_TERMS",
    "REWARD_TERMS",
    "TEAMMATE",
    "TEAMS",
    "WALL",
    "other_team",
]
