"""Whole episodes of many arenas at once, for evaluation: every arena plays until it is done."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from pe_mjx.config import TEAMS
from pe_mjx.env import PursuitEvasionEnv, State
from pe_mjx.match import rollout
from pe_mjx.policies import Policy


def play_episodes(
    env: PursuitEvasionEnv,
    policies: dict[str, Policy],
    keys: jax.Array,
    record: bool = False,
) -> State | tuple[State, dict[str, jax.Array]]:
    """Plays one episode per key (one vmapped batch of B arenas) until every one is done.

    Arena i's episode (its reset and every action sampled) depends on `keys[i]` alone, exactly as
    `match.rollout(env, policies, keys[i], max_steps)`, so a subset of trials can be replayed with
    a subset of the keys. Not jitted here; jit the caller.

    Args:
      env: the env (no auto-reset).
      policies: team -> `(obs, rng) -> int32 [A]` for one arena.
      keys: [B] PRNG keys, one per arena.
      record: also return the trajectory: poses [max_steps + 1, B, N, 3] and active
        [max_steps + 1, B, N] (after an arena ended, its frames repeat its final state).

    Returns:
      The batched final state [B], and with `record` the trajectory dict.
    """
    max_steps = env.config.max_steps
    if not record:
        return jax.vmap(lambda k: rollout(env, policies, k, max_steps))(keys)

    def one_arena(rng):
        rng, reset_rng = jax.random.split(rng)
        state = env.reset(reset_rng)

        def body(carry, _):
            s, key = carry
            key, *team_keys = jax.random.split(key, len(TEAMS) + 1)
            actions = {t: policies[t](s.obs[t], k) for t, k in zip(TEAMS, team_keys, strict=True)}
            nxt = env.step(s, actions)
            finished = s.done > 0
            s = jax.tree.map(lambda old, new: jnp.where(finished, old, new), s, nxt)
            return (s, key), pose_of(s)

        (final, _), frames = jax.lax.scan(body, (state, rng), None, length=max_steps)
        first = pose_of(state)
        traj = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, frames)
        return final, traj

    def pose_of(s: State) -> dict[str, jax.Array]:
        w = s.world
        return {"poses": jnp.concatenate([w.pos, w.yaw[..., None]], axis=-1), "active": w.active}

    final, traj = jax.vmap(one_arena)(keys)
    # vmap puts the arena axis first; the trajectory format is time-major [T, B, ...].
    traj = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), traj)
    return final, traj
