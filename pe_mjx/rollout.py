"""Acting for both teams and playing episodes: one home for the loop every caller runs.

`act` asks each team's policy for its actions (the key split every episode uses), `freeze` keeps
finished arenas as they ended, and `rollout` plays one arena to its end, jittable and vmappable:
a `while_loop` that stops at `done`, or with `record=True` a `scan` of fixed length that also
returns every frame. Both run the same step (`act`, then `env.step`), so an arena plays the same
episode whichever is asked for. `episodes.play_episodes` (many arenas) and the viewer's `LiveRun`
build on these; the trainer's rollout is its own (it also keeps log-probabilities and values).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from pe_mjx.env import PursuitEvasionEnv, State
from pe_mjx.names import TEAMS
from pe_mjx.policy.core import Policy


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
    returns: bool = False,
    record: bool = False,
) -> Any:
    """Plays one arena until it is done or `steps` control steps were taken.

    Pure and jittable (``env`` and ``policies`` are static: close over them or use
    ``functools.partial``; ``steps`` may be a Python int or a traced int32 scalar, so one compile
    serves every budget, except with ``record``, whose frames need a Python int); ``jax.vmap`` it
    over ``rng`` (and ``state``) for many arenas. Under ``vmap`` finished arenas are frozen while
    the others play on.

    Args:
      env: the env (not auto-resetting: the loop stops at ``done``).
      policies: {"pursuer": policy, "evader": policy}, each ``(obs of its team, rng) -> int32 [A]``.
      rng: key; when ``state`` is None the episode starts from ``env.reset`` of a key split off it.
      steps: at most this many control steps (the env's own time limit also ends the episode).
      state: optional start state (for example from ``env.reset_to``).
      returns: also return each agent's episodic return: team -> float32 [A], the sum of its
        (unscaled) rewards over the episode (0 after it is down).
      record: also return the trajectory: ``poses`` [steps + 1, N, 3] and ``active``
        [steps + 1, N] (after the arena ended, its frames repeat its final state).

    Returns:
      The state after the last step taken (``state.done`` set if the episode ended: terminated,
      or truncated at ``max_steps``); with `record` and/or `returns` a tuple ``(final,
      trajectory)``, ``(final, returns)`` or ``(final, trajectory, returns)``.
    """
    missing = set(TEAMS) - set(policies)
    if missing:
        raise ValueError(f"rollout: policies missing for teams {sorted(missing)}")
    if isinstance(steps, int) and steps < 0:
        raise ValueError(f"rollout: steps must be >= 0, got {steps}")
    if record and not isinstance(steps, int):
        raise ValueError("rollout: record=True needs steps as a Python int (the frame count)")
    rng, reset_rng = jax.random.split(rng)
    if state is None:
        state = env.reset(reset_rng)
    start = state.world.step
    # Returns are summed only when asked for: the plain loop carries no extra work.
    ret = {t: jnp.zeros_like(state.reward[t]) for t in TEAMS} if returns else {}

    def step(s: State, key: jax.Array, ret: dict, playing: jax.Array):
        actions, key = act(policies, s.obs, key)
        nxt = env.step(s, actions)
        if record:  # a fixed-length scan: an arena that is done keeps its last state
            nxt = freeze(s, nxt)
        # The env's reward is already 0 for agents that were down before the step.
        ret = {t: r + jnp.where(playing, nxt.reward[t], 0.0) for t, r in ret.items()}
        return nxt, key, ret

    if record:

        def scan_body(carry, _):
            s, key, r = carry
            s, key, r = step(s, key, r, s.done == 0)
            return (s, key, r), _pose(s)

        (final, _, ret), frames = jax.lax.scan(scan_body, (state, rng, ret), None, length=steps)
        first = _pose(state)
        trajectory = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, frames)
        return (final, trajectory, ret) if returns else (final, trajectory)

    def cond(carry: tuple[State, jax.Array, dict]) -> jax.Array:
        s = carry[0]
        return (s.world.step - start < steps) & (s.done == 0)

    def body(carry: tuple[State, jax.Array, dict]) -> tuple[State, jax.Array, dict]:
        s, key, r = carry
        return step(s, key, r, jnp.bool_(True))

    final, _, ret = jax.lax.while_loop(cond, body, (state, rng, ret))
    return (final, ret) if returns else final


def _pose(s: State) -> dict[str, jax.Array]:
    w = s.world
    return {"poses": jnp.concatenate([w.pos, w.yaw[..., None]], axis=-1), "active": w.active}


__all__ = ["act", "freeze", "rollout"]
