"""The one policy type: a team's policy, resolved once, ready to play wherever it runs.

Every consumer (the trainer's opponents and evaluation, `pe-mjx evaluate`, the viewer, the
adapters, export) holds a `Policy`. It is callable like a plain policy function::

    policy(obs, rng) -> int32 [A]

where ``obs`` is one team's observation dict with any leading dims ([A, ...] for one arena), and
it also carries its learned state as data: ``policy.apply(policy.variables, obs, rng)`` is the same
call with the parameters as an *input*, so that a jitted caller compiles once per network shape
(the evaluator once per `shape_key`, the viewer once however often training swaps parameters).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.experiment import NetworkConfig

PolicyFn = Callable[[dict[str, jax.Array], jax.Array], jax.Array]
"""A plain policy function: (one team's obs, rng) -> int32 actions (hand-written policies,
exported ones wrapped to take the rng; a `Policy` is one too)."""
ApplyFn = Callable[[Any, dict[str, jax.Array], jax.Array], jax.Array]
"""(variables, one team's obs, rng) -> int32 actions."""
AttentionApplyFn = Callable[
    [Any, dict[str, jax.Array], jax.Array], tuple[jax.Array, jax.Array | None]
]
"""(variables, one team's obs of one arena, rng) -> (int32 actions [A], attention [A, M] | None)."""


@dataclasses.dataclass(frozen=True)
class Policy:
    """One team's policy: where it came from, how it is labelled, and how it acts."""

    team: str
    source: str
    """The spec it was resolved from: a builtin name, a run directory as given, a shipped
    policy's name, or "training" (the live trainer's parameters)."""
    label: str
    """The paper's label: "P_scripted", "E_MIX(20,5,8)" (the training counts), "*" if padded."""
    method: str
    """The encoder of a learned policy ("mix", ...); the builtin name for builtin ones."""
    apply: ApplyFn
    """`apply(variables, obs, rng) -> actions`: the policy with its learned state as an input."""
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
    """Greedy actions (True) or sampled ones; meaningful for learned policies only."""
    attention_apply: AttentionApplyFn | None = None
    """For MIX networks: `apply` that also returns each agent's own-token attention over its
    tokens (mean over heads), which the viewer draws; None for every other policy."""

    def __call__(self, obs: dict[str, jax.Array], rng: jax.Array) -> jax.Array:
        return self.apply(self.variables, obs, rng)

    @property
    def learned(self) -> bool:
        return self.variables is not None

    @functools.cached_property
    def fingerprint(self) -> str:
        """A digest of what decides how the policy acts: its team, program (`shape_key`), label,
        note, greedy or sampled actions, and every array of its learned state with its path,
        shape and dtype. Equal fingerprints play equal games under the same code; where it came
        from (`source`) does not enter it."""
        digest = hashlib.sha256()
        fields = [self.team, self.shape_key, self.label, self.note, self.deterministic]
        digest.update(json.dumps(fields).encode())
        leaves, _ = jax.tree_util.tree_flatten_with_path(self.variables)
        for path, leaf in leaves:
            array = np.asarray(leaf)
            head = [jax.tree_util.keystr(path), list(array.shape), array.dtype.str]
            digest.update(json.dumps(head).encode())
            digest.update(np.ascontiguousarray(array).tobytes())
        return digest.hexdigest()[:32]

    def with_attention(self) -> AttentionApplyFn:
        """`(variables, obs, rng) -> (int32 actions, attention or None)` for every policy."""
        if self.attention_apply is not None:
            return self.attention_apply
        apply = self.apply

        def no_attention(variables: Any, obs: dict[str, jax.Array], rng: jax.Array):
            return apply(variables, obs, rng).astype(jnp.int32), None

        return no_attention


def team_letter(team: str) -> str:
    """The paper's prefix of a team's labels: "P" or "E"."""
    return "P" if team == "pursuer" else "E"


def builtin_policy(name: str, team: str, fn: PolicyFn) -> Policy:
    """A `Policy` around a hand-written `fn(obs, rng) -> actions` (scripted, random)."""
    return Policy(
        team=team,
        source=name,
        label=f"{team_letter(team)}_{name}",
        method=name,
        apply=lambda variables, obs, rng: fn(obs, rng),
        shape_key=f"builtin:{name}",
    )


__all__ = ["ApplyFn", "AttentionApplyFn", "Policy", "PolicyFn", "builtin_policy", "team_letter"]
