"""The scripted demo match and the plain-Python summary of one finished episode."""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from pe_mjx.config import get_preset
from pe_mjx.env import PursuitEvasionEnv, State
from pe_mjx.names import CAUSE_NAMES, TEAMS
from pe_mjx.outcomes import outcome_counts
from pe_mjx.policy.scripted import make_policy
from pe_mjx.rollout import rollout


def match_summary(env: PursuitEvasionEnv, state: State) -> dict[str, Any]:
    """Plain-Python outcome of one finished (unbatched) episode.

    Keys: ``steps``, ``evaders_captured``, ``evaders_total``, ``pursuers_total``,
    ``pursuers_<cause>`` and ``evaders_<cause>`` (incapacitated by wall, obstacle, capture,
    teammate, opponent), ``pursuers_active``, ``evaders_active``, ``success_rate`` (SPEC 4: n'/n,
    n' the evaders incapacitated by any cause), ``pursuit_cost`` (m'), ``mean_pursuer_distance``
    (metres), ``terminated`` (a team is out) and ``truncated`` (cut by the time limit or the step
    budget instead).
    """
    w = jax.device_get(state.world)
    counts = outcome_counts(w.cause, w.distance, env.num_pursuers)
    out: dict[str, Any] = {"steps": int(w.step)}
    out["evaders_captured"] = int(counts["evaders_capture"])
    out["evaders_total"] = env.num_evaders
    out["pursuers_total"] = env.num_pursuers
    for who in ("pursuers", "evaders"):
        for name in CAUSE_NAMES.values():
            out[f"{who}_{name}"] = int(counts[f"{who}_{name}"])
        out[f"{who}_active"] = int(counts[f"{who}_active"])
    out["success_rate"] = float(counts["success_rate"])
    out["pursuit_cost"] = int(counts["pursuit_cost"])
    out["mean_pursuer_distance"] = round(float(counts["travel_distance"]), 4)
    terminated = bool(jax.device_get(state.info["terminated"]))
    out["terminated"] = terminated
    out["truncated"] = not terminated
    return out


@functools.cache
def _scripted_match(preset: str, backend: str) -> tuple[PursuitEvasionEnv, Any]:
    """(env, jitted (key, steps) -> final state) of scripted matches; cached: one compile each."""
    config = get_preset(preset)
    env = PursuitEvasionEnv(config, backend=backend)
    policies = {team: make_policy("scripted", config, team) for team in TEAMS}
    return env, jax.jit(lambda key, steps: rollout(env, policies, key, steps))


def play_scripted_match(preset: str, seed: int, backend: str, steps: int) -> dict[str, Any]:
    """One episode, scripted pursuers against scripted evaders, jitted; returns its summary.

    Args:
      preset: scenario preset name (see `pe_mjx.config.PRESETS`).
      seed: seed of the arena draw (``jax.random.key(seed)``).
      backend: "mjx" or "kinematic".
      steps: control steps at most (the env's ``max_steps`` also ends the episode).

    Returns:
      `match_summary` of the final state (plain Python ints, floats and bools).
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    env, play = _scripted_match(preset, backend)
    # The env ends every episode at max_steps anyway; the clamp keeps the budget in int32.
    budget = jnp.int32(min(steps, env.config.max_steps))
    return match_summary(env, play(jax.random.key(seed), budget))


__all__ = ["match_summary", "play_scripted_match"]
