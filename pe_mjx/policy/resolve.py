"""The one resolver from a policy spec to a `Policy`, for the trainer, evaluator, viewer, export.

A *policy spec* is a builtin name ("scripted", "random"), a run directory of `pe-mjx train` or
the name of a shipped policy ("mix-20-5-8", `pe_mjx.policy.shipped`). `resolve_policy` reads a
run's checkpoint metadata once (`pe_mjx.policy.store`), restores the team's network and
observation statistics, checks the action count against the scene, and returns a `Policy`
(`pe_mjx.policy.core`): callable as `policy(obs, rng)`, and with its variables as data for
callers that compile once per network shape.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pe_mjx.config import EnvConfig
from pe_mjx.names import BUILTIN_POLICIES, TEAMS
from pe_mjx.policy.core import Policy, team_letter
from pe_mjx.policy.inference import learned_policy
from pe_mjx.policy.scripted import make_policy
from pe_mjx.policy.store import CheckpointError, restore_policy_params


def resolve_policy(
    spec: str | Path,
    team: str,
    env_config: EnvConfig | None = None,
    deterministic: bool = False,
    fallback: bool = False,
) -> Policy:
    """Turns a policy spec into a ready policy for `team` in scenes of `env_config`.

    Args:
      spec: "scripted", "random", a run directory or a shipped policy's name.
      team: "pursuer" or "evader".
      env_config: the scene it will play; a run's action count must match it, and a network
        with a `length_unit` reads lengths for its arena radius. None: a run plays the scene it
        was trained in (builtin policies need a scene).
      deterministic: greedy actions instead of sampling (learned policies).
      fallback: when the run's latest checkpoint is damaged, play its latest intact one (with a
        warning line) instead of raising the `DamagedCheckpointError` that names it.

    Raises:
      ValueError: an unknown team; `CheckpointError` (a ValueError) for a run that is missing,
        unreadable, did not learn `team`, or whose action count does not fit the scene.
    """
    if team not in TEAMS:
        raise CheckpointError(f"unknown team {team!r}; expected one of {TEAMS}")
    if not isinstance(spec, str | Path):
        raise TypeError(f"spec must be a str or a Path, got {type(spec).__name__}")
    for name, flag in (("deterministic", deterministic), ("fallback", fallback)):
        if not isinstance(flag, bool | np.bool_):  # "yes" and "no" were both truthy
            raise TypeError(f"{name} must be True or False, got {flag!r}")
    if not str(spec):  # "" was the working directory
        raise CheckpointError("empty policy spec: give a builtin name, a run or a shipped name")
    if env_config is not None and not isinstance(env_config, EnvConfig):
        raise TypeError(
            f"env_config must be an EnvConfig (e.g. pe_mjx.get_preset('20-5-8')) or None, got "
            f"{type(env_config).__name__}"
        )
    if str(spec) in BUILTIN_POLICIES:
        name = str(spec)
        if env_config is None:
            raise ValueError(f"the {name} policy needs the env config of the scene it plays")
        return make_policy(name, env_config, team)
    restored = restore_policy_params(spec, team, env_config, fallback=fallback)
    network, variables, net_config, env_config, trained, meta = restored
    counts = (trained.pursuer.num_agents, trained.evader.num_agents, trained.arena.num_obstacles)
    here = (env_config.pursuer.num_agents, env_config.evader.num_agents)
    here += (env_config.arena.num_obstacles,)
    method = net_config.encoder.upper()
    if net_config.nearest_k is not None:  # local attention: the k nearest of each type
        method += f"-k{net_config.nearest_k}"
    if net_config.length_unit is not None:  # neighbour lengths in metres
        method += f"-{net_config.length_unit:g}m"
    label = f"{team_letter(team)}_{method}({counts[0]},{counts[1]},{counts[2]})"
    note = ""
    if net_config.encoder == "mlp" and here != counts:
        # SPEC 3.1: an MLP cannot generalise; its input is padded/truncated to its training counts.
        note = "mlp-padded"
        label += "*"
    net = meta["network_configs"][team]
    num_actions = int(meta["num_actions"][team])
    return learned_policy(
        team,
        network,
        net_config,
        variables,
        source=str(spec),
        label=label,
        deterministic=deterministic,
        env_config=env_config,
        shape_key=f"net:{num_actions}:{deterministic}:{json.dumps(net, sort_keys=True)}",
        note=note,
    )


def load_policy(
    spec: str | Path,
    team: str,
    deterministic: bool = False,
    env_config: EnvConfig | None = None,
    fallback: bool = False,
) -> Policy:
    """`resolve_policy` with the argument order of the package's first API (`pe_mjx.load_policy`).

    Args:
      spec: a `pe-mjx train --out` directory, or the name of a shipped policy
        ("mix-20-5-8"; `pe_mjx.policy.shipped.shipped_names()`); "scripted" and "random" need
        `env_config`.
      team: "pursuer" or "evader".
      deterministic: greedy actions instead of sampling.
      env_config: the scene it will play, if given: checked for compatibility (the team's
        action count), and its arena radius is what a policy with a `length_unit` converts
        neighbour lengths with (default: the scene it was trained in).
      fallback: when the run's latest checkpoint is damaged, play its latest intact one (with a
        warning line) instead of raising the `DamagedCheckpointError` that names it.

    Returns:
      The team's `Policy`: jittable `policy(obs, rng) -> int32 [...]`, obs being that team's
      observation dict with any leading dims ([A, ...] for one arena).
    """
    return resolve_policy(spec, team, env_config, deterministic, fallback)


__all__ = ["load_policy", "resolve_policy"]
