"""Whole episodes of many arenas at once, for evaluation: every arena plays until it is done."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from pe_mjx.env import PursuitEvasionEnv, State
from pe_mjx.names import TEAMS
from pe_mjx.policies import Policy
from pe_mjx.rollout import act, freeze, rollout


def play_episodes(
    env: PursuitEvasionEnv,
    policies: dict[str, Policy],
    keys: jax.Array,
    record: bool = False,
    returns: bool = False,
) -> State | tuple:
    """Plays one episode per key (one vmapped batch of B arenas) until every one is done.

    Arena i's episode (its reset and every action sampled) depends on `keys[i]` alone, exactly as
    `rollout(env, policies, keys[i], max_steps)`, so a subset of trials can be replayed with
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
    if not record and not returns:
        return jax.vmap(lambda k: rollout(env, policies, k, max_steps))(keys)

    def step(s: State, key: jax.Array) -> tuple[State, jax.Array]:
        # `act` splits keys as `rollout` does, so that every path plays the same episode.
        actions, key = act(policies, s.obs, key)
        return env.step(s, actions), key

    def zero_returns(s: State) -> dict[str, jax.Array]:
        return {t: jnp.zeros_like(s.reward[t]) for t in TEAMS}

    def add(ret: dict[str, jax.Array], s: State, gained: jax.Array) -> dict[str, jax.Array]:
        # The env's reward is already 0 for agents that were down before the step.
        return {t: ret[t] + jnp.where(gained, s.reward[t], 0.0) for t in TEAMS}

    def pose_of(s: State) -> dict[str, jax.Array]:
        w = s.world
        return {"poses": jnp.concatenate([w.pos, w.yaw[..., None]], axis=-1), "active": w.active}

    def one_arena_returns(rng):
        # As `rollout`, the while loop stops at `done` (under vmap, finished arenas freeze).
        rng, reset_rng = jax.random.split(rng)
        state = env.reset(reset_rng)

        def body(carry):
            s, key, ret = carry
            nxt, key = step(s, key)
            return nxt, key, add(ret, nxt, True)

        def cond(carry):
            s, _, _ = carry
            return (s.world.step < max_steps) & (s.done == 0)

        final, _, ret = jax.lax.while_loop(cond, body, (state, rng, zero_returns(state)))
        return final, ret

    def one_arena_recorded(rng):
        rng, reset_rng = jax.random.split(rng)
        state = env.reset(reset_rng)

        def body(carry, _):
            s, key, ret = carry
            nxt, key = step(s, key)
            finished = s.done > 0
            s = freeze(s, nxt)
            ret = add(ret, s, ~finished)
            return (s, key, ret), pose_of(s)

        (final, _, ret), frames = jax.lax.scan(
            body, (state, rng, zero_returns(state)), None, length=max_steps
        )
        first = pose_of(state)
        traj = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, frames)
        return final, traj, ret

    if not record:
        return jax.vmap(one_arena_returns)(keys)
    final, traj, ret = jax.vmap(one_arena_recorded)(keys)
    # vmap puts the arena axis first; the trajectory format is time-major [T, B, ...].
    traj = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), traj)
    return (final, traj, ret) if returns else (final, traj)
