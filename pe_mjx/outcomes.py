"""One count of how episodes ended: causes of incapacitation, success rate, pursuit cost.

The evaluator (`trial_metrics`), the demo (`match.match_summary`) and the viewer's counters count
with `outcome_counts`, so that they agree by construction. Plain array operators only: it takes
numpy or jax arrays, unbatched [N] or with any leading dims [..., N].
"""

from __future__ import annotations

from typing import Any

from pe_mjx.names import ABSENT, ACTIVE, CAUSE_NAMES


def outcome_counts(cause: Any, distance: Any, num_pursuers: int) -> dict[str, Any]:
    """Outcome of episodes from the final `World.cause` and `World.distance`.

    Args:
      cause: int [..., N], the incapacitation cause of every agent (pursuers first), 0 = active.
      distance: float [..., N], the distance each agent travelled (metres).
      num_pursuers: P, the number of pursuers among the N agents.

    Returns:
      Arrays of shape [...]: ``pursuers_<cause>`` and ``evaders_<cause>`` (agents downed by each
      cause of `names.CAUSE_NAMES`), ``pursuers_active``, ``evaders_active``,
      ``evaders_incapacitated`` (n'), ``success_rate`` (n'/n, SPEC 4: an evader counts whether it
      was captured or crashed), ``pursuit_cost`` (m', the pursuers downed) and
      ``travel_distance`` (the pursuers' mean distance travelled). Agents absent from the
      episode (`names.ABSENT`, `TeamConfig.min_agents`) count nowhere: n and m are the agents
      present (``pursuers_present``, ``evaders_present``).
    """
    p = num_pursuers
    out: dict[str, Any] = {}
    present = {}
    for who, codes in (("pursuers", cause[..., :p]), ("evaders", cause[..., p:])):
        for code, name in CAUSE_NAMES.items():
            out[f"{who}_{name}"] = (codes == code).sum(axis=-1)
        out[f"{who}_active"] = (codes == ACTIVE).sum(axis=-1)
        present[who] = codes != ABSENT
        out[f"{who}_present"] = present[who].sum(axis=-1)
    out["evaders_incapacitated"] = out["evaders_present"] - out["evaders_active"]
    out["success_rate"] = out["evaders_incapacitated"] / out["evaders_present"]
    out["pursuit_cost"] = out["pursuers_present"] - out["pursuers_active"]
    travelled = (distance[..., :p] * present["pursuers"]).sum(axis=-1)
    # In the distances' dtype: numpy divides float32 by an integer count in float64; rounded back,
    # a scene with every agent present gives exactly the plain mean of earlier versions.
    out["travel_distance"] = (travelled / out["pursuers_present"]).astype(distance.dtype)
    return out


__all__ = ["outcome_counts"]
