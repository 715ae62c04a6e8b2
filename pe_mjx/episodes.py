"""Whole episodes of many arenas at once, for evaluation: every arena plays until it is done."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from pe_mjx.env import PursuitEvasionEnv, State
from pe_mjx.policy.core import Policy
from pe_mjx.rollout import rollout


def play_episodes(
    env: PursuitEvasionEnv,
    policies: dict[str, Policy],
    keys: jax.Array,
    record: bool = False,
    returns: bool = False,
) -> State | tuple:
    """Plays one episode per key (one vmapped batch of B arenas) until every one is done.

    Each arena is `rollout(env, policies, keys[i], max_steps, ...)`: its episode (its reset and
    every action sampled) depends on `keys[i]` alone, so a subset of trials can be replayed with
    a subset of the keys. Not jitted here; jit the caller.

    Args:
      env: the env (no auto-reset).
      policies: team -> `(obs, rng) -> int32 [A]` for one arena.
      keys: [B] PRNG keys, one per arena.
      record: also return the trajectory: poses [max_steps + 1, B, N, 3] and active
        [max_steps + 1, B, N] (after an arena ended, its frames repeat its final state).
      returns: also return each agent's episodic return: team -> float32 [B, A], the sum of its
        (unscaled) rewards over its arena's episode (0 after it is down or the arena ended).

    Returns:
      The batched final state [B]; with `record` and/or `returns` a tuple `(final, trajectory)`,
      `(final, returns)` or `(final, trajectory, returns)`.
    """
    max_steps = env.config.max_steps

    def one_arena(key: jax.Array):
        return rollout(env, policies, key, max_steps, returns=returns, record=record)

    out = jax.vmap(one_arena)(keys)
    if not record:
        return out
    # vmap puts the arena axis first; the trajectory format is time-major [T, B, ...].
    final, trajectory, *rest = out
    trajectory = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), trajectory)
    return (final, trajectory, *rest)
