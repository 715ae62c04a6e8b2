"""One resolver from a policy spec to a ready play-time policy, for the trainer, evaluator, viewer.

A *policy spec* is a builtin name ("scripted", "random"), a run directory of `pe-mjx train` or
the name of a shipped policy ("mix-20-5-8", `pe_mjx.shipped`). `resolve_policy` reads a run's
checkpoint metadata once, restores the team's network and observation statistics, checks the
action count against the scene, and returns a `PlayPolicy` with both forms of the policy: closed
over its variables (`policy(obs, rng)`) and with them as an argument (`apply(variables, obs,
rng)`, so that one compile serves every policy of a network shape). The network is kept for the
viewer's attention variant (`agents.attention_policy_apply`).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from pe_mjx.agents import Policy, learned_policy, policy_apply
from pe_mjx.config import EnvConfig
from pe_mjx.names import BUILTIN_POLICIES, TEAMS
from pe_mjx.networks import NetworkConfig
from pe_mjx.policies import make_policy
from pe_mjx.ppo.checkpoint import CheckpointError, restore_policy_params
from pe_mjx.shipped import resolve_run


@dataclasses.dataclass(frozen=True)
class PlayPolicy:
    """A policy for one team, resolved: its label, where it came from, and the callables."""

    team: str
    source: str
    """The spec it was resolved from (a builtin name, or the run directory as given)."""
    label: str
    """The paper's label: "P_scripted", "E_MIX(20,5,8)" (the training counts), "*" if padded."""
    policy: Policy
    """`(obs, rng) -> int32 actions`, jittable, obs of one team with any leading dims."""
    method: str
    """The encoder of a learned policy ("mix", ...); the spec itself for builtin ones."""
    apply: Callable[..., jax.Array]
    """`apply(variables, obs, rng) -> actions`: `policy` with its learned state as an input."""
    variables: Any = None
    """The learned state `apply` takes ({"params", "normalizer"}; None for builtin ones)."""
    shape_key: str = ""
    """Equal for policies whose `apply` compiles to the same program (same network config and
    action count, or the same builtin policy): one compile serves them all."""
    note: str = ""
    """"mlp-padded" for an MLP played at other entity counts than it was trained on."""
    network: Any = None
    """The `networks.ActorCritic` module of a learned policy (None for builtin ones)."""
    network_config: NetworkConfig | None = None
    deterministic: bool = False

    @property
    def learned(self) -> bool:
        return self.variables is not None


def team_letter(team: str) -> str:
    return "P" if team == "pursuer" else "E"


def resolve_policy(
    spec: str | Path, team: str, env_config: EnvConfig | None, deterministic: bool = False
) -> PlayPolicy:
    """Turns a policy spec into a ready policy for `team` in scenes of `env_config`.

    Args:
      spec: "scripted", "random", a run directory or a shipped policy's name.
      team: "pursuer" or "evader".
      env_config: the scene it will play; a run's action count must match it. None: a run
        plays the scene it was trained in (builtin policies need a scene).
      deterministic: greedy actions instead of sampling (learned policies).

    Raises:
      ValueError: an unknown team; `CheckpointError` (a ValueError) for a run that is missing,
        unreadable, did not learn `team`, or whose action count does not fit the scene.
    """
    if team not in TEAMS:
        raise CheckpointError(f"unknown team {team!r}; expected one of {TEAMS}")
    if str(spec) in BUILTIN_POLICIES:
        name = str(spec)
        if env_config is None:
            raise ValueError(f"the {name} policy needs the env config of the scene it plays")
        policy = make_policy(name, env_config, team)
        return PlayPolicy(
            team=team,
            source=name,
            label=f"{team_letter(team)}_{name}",
            policy=policy,
            method=name,
            apply=lambda variables, obs, rng: policy(obs, rng),
            shape_key=f"builtin:{name}",
        )
    network, variables, net_config, meta = restore_policy_params(resolve_run(spec), team)
    trained = EnvConfig.from_dict(meta["env_config"])
    env_config = trained if env_config is None else env_config
    have, want = int(meta["num_actions"][team]), env_config.team(team).num_actions
    if have != want:
        raise CheckpointError(
            f"the {team} policy in {spec} has {have} actions but this scene's {team}s have {want}"
        )
    counts = (trained.pursuer.num_agents, trained.evader.num_agents, trained.arena.num_obstacles)
    here = (env_config.pursuer.num_agents, env_config.evader.num_agents)
    here += (env_config.arena.num_obstacles,)
    label = f"{team_letter(team)}_{net_config.encoder.upper()}({counts[0]},{counts[1]},{counts[2]})"
    note = ""
    if net_config.encoder == "mlp" and here != counts:
        # SPEC 3.1: an MLP cannot generalise; its input is padded/truncated to its training counts.
        note = "mlp-padded"
        label += "*"
    net = meta["network_configs"][team]
    return PlayPolicy(
        team=team,
        source=str(spec),
        label=label,
        policy=learned_policy(network, variables["params"], variables["normalizer"], deterministic),
        method=net_config.encoder,
        apply=policy_apply(network, deterministic),
        variables=variables,
        shape_key=f"net:{have}:{deterministic}:{json.dumps(net, sort_keys=True)}",
        note=note,
        network=network,
        network_config=net_config,
        deterministic=deterministic,
    )


def load_policy(
    spec: str | Path,
    team: str,
    deterministic: bool = False,
    env_config: EnvConfig | None = None,
) -> Policy:
    """Rebuilds a team's policy from a run directory (or a shipped policy's name) alone.

    Args:
      spec: a `pe-mjx train --out` directory, or the name of a shipped policy
        ("mix-20-5-8"; `pe_mjx.shipped.shipped_names()`); "scripted" and "random" need
        `env_config`.
      team: "pursuer" or "evader".
      deterministic: greedy actions instead of sampling.
      env_config: if given, checked for compatibility (the team's action count).

    Returns:
      A jittable `policy(obs, rng) -> int32 [...]`, obs being that team's observation dict with
      any leading dims ([A, ...] for one arena).
    """
    return resolve_policy(spec, team, env_config, deterministic).policy


__all__ = ["PlayPolicy", "load_policy", "resolve_policy", "team_letter"]
