"""Acting for both teams and playing episodes: one home for the loop every caller runs.

`act` asks each team's policy for its actions (the key split every episode uses), `freeze` keeps
finished arenas as they ended, and `rollout` plays one arena to its end, jittable and vmappable.
`episodes.play_episodes` (many arenas, recording) and the viewer's `LiveRun` build on these.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from pe_mjx.env import PursuitEvasionEnv, State
from pe_mjx.names import TEAMS

Policy = Callable[[dict[str, jax.Array], jax.Array], jax.Array]
"""`(obs of one team, rng) -> int32 actions`, obs with leading dims [A] for one arena."""


def act(
    policies: dict[str, Policy], obs: dict[str, dict[str, jax.Array]], rng: jax.Array
) -> tuple[dict[str, jax.Array], jax.Array]:
    """Both teams' actions on one arena's observations, and the key to carry on with.

    Args:
      policies: team -> policy.
      obs: team -> that team's observation dict ([A, ...]).
      rng: key; split into the next carry key and one key per team (in `TEAMS` order).

    Returns:
      (team -> int32 [A], next rng).
    """
    rng, *team_keys = jax.random.split(rng, len(TEAMS) + 1)
    actions = {t: policies[t](obs[t], k) for t, k in zip(TEAMS, team_keys, strict=True)}
    return actions, rng


def freeze(old: State, new: State) -> State:
    """`new`, except for arenas already done in `old`, which keep `old` (batched or not)."""
    finished = old.done > 0

    def keep(a: jax.Array, b: jax.Array) -> jax.Array:
        mask = finished.reshape(finished.shape + (1,) * (b.ndim - finished.ndim))
        return jnp.where(mask, a, b)

    return jax.tree.map(keep, old, new)


def rollout(
    env: PursuitEvasionEnv,
    policies: dict[str, Policy],
    rng: jax.Array,
    steps: int | jax.Array,
    state: State | None = None,
) -> State:
    """Plays one arena until it is done or `steps` control steps were taken; returns the last state.

    Pure and jittable (``env`` and ``policies`` are static: close over them or use
    ``functools.partial``; ``steps`` may be a Python int or a traced int32 scalar, so one compile
    serves every budget); ``jax.vmap`` it over ``rng`` (and ``state``) for many arenas. Under
    ``vmap`` finished arenas are frozen while the others play on.

    Args:
      env: the env (not auto-resetting: the loop stops at ``done``).
      policies: {"pursuer": policy, "evader": policy}, each ``(obs of its team, rng) -> int32 [A]``.
      rng: key; when ``state`` is None the episode starts from ``env.reset`` of a key split off it.
      steps: at most this many control steps (the env's own time limit also ends the episode).
      state: optional start state (for example from ``env.reset_to``).

    Returns:
      The state after the last step taken: ``state.world.step`` steps, ``state.done`` set if the
      episode ended (terminated, or truncated at ``max_steps``).
    """
    missing = set(TEAMS) - set(policies)
    if missing:
        raise ValueError(f"rollout: policies missing for teams {sorted(missing)}")
    if isinstance(steps, int) and steps < 0:
        raise ValueError(f"rollout: steps must be >= 0, got {steps}")
    rng, reset_rng = jax.random.split(rng)
    if state is None:
        state = env.reset(reset_rng)
    start = state.world.step

    def cond(carry: tuple[State, jax.Array]) -> jax.Array:
        s, _ = carry
        return (s.world.step - start < steps) & (s.done == 0)

    def body(carry: tuple[State, jax.Array]) -> tuple[State, jax.Array]:
        s, key = carry
        actions, key = act(policies, s.obs, key)
        return env.step(s, actions), key

    final, _ = jax.lax.while_loop(cond, body, (state, rng))
    return final


__all__ = ["Policy", "act", "freeze", "rollout"]
