"""Per-step scalars: `reward/<team>/<term>` this step, `episode/*` so far, `invalid_actions`."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from pe_mjx.config import EnvConfig
from pe_mjx.names import ABSENT, CAUSE_NAMES, TEAMS
from pe_mjx.outcomes import outcome_counts
from pe_mjx.stages.rewards import Terms
from pe_mjx.stages.world import World


def step_metrics(
    config: EnvConfig,
    world: World,
    terms: Terms,
    valid: dict[str, jax.Array],
    invalid_actions: jax.Array,
) -> dict[str, jax.Array]:
    """Scalars (float32 []) of one arena after a step.

    `reward/<team>/<term>`: the term summed over the team's `valid` agents (bool [A], those
    active before the step); `episode/<team>_<cause>` (agents downed by each cause),
    `episode/<team>_distance` (mean distance travelled), `episode/captures`,
    `episode/success_rate`, `episode/pursuit_cost` (`outcomes.outcome_counts`) and
    `episode/length` of the episode so far; `invalid_actions`: out-of-range action indices given
    this step (`dynamics.Commands.invalid_actions`).
    """
    metrics = {"invalid_actions": invalid_actions}
    for team, team_terms in terms.items():
        for name, value in team_terms.items():
            metrics[f"reward/{team}/{name}"] = jnp.sum(jnp.where(valid[team], value, 0.0))
    p = config.pursuer.num_agents
    counts = outcome_counts(world.cause, world.distance, p)
    for team, s in zip(TEAMS, (slice(0, p), slice(p, None)), strict=True):
        for name in CAUSE_NAMES.values():
            metrics[f"episode/{team}_{name}"] = counts[f"{team}s_{name}"].astype(jnp.float32)
        present = world.cause[s] != ABSENT
        travelled = jnp.sum(jnp.where(present, world.distance[s], 0.0))
        metrics[f"episode/{team}_distance"] = travelled / jnp.sum(present)
    metrics["episode/captures"] = jnp.sum(world.captures[p:]).astype(jnp.float32)
    metrics["episode/success_rate"] = counts["success_rate"]
    metrics["episode/pursuit_cost"] = counts["pursuit_cost"].astype(jnp.float32)
    metrics["episode/length"] = world.step.astype(jnp.float32)
    return metrics


__all__ = ["step_metrics"]
