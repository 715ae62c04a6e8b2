"""Whole episodes of many arenas at once, for evaluation: every arena plays until it is done."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from pe_mjx.config import TEAMS
from pe_mjx.env import PursuitEvasionEnv, State

Policy = Callable[[dict[str, jax.Array], jax.Array], jax.Array]


def play_episodes(
    env: PursuitEvasionEnv,
    policies: dict[str, Policy],
    rng: jax.Array,
    num_episodes: int,
    record: bool = False,
) -> State | tuple[State, dict[str, jax.Array]]:
    """Plays `num_episodes` arenas (one vmapped batch) until every one is done.

    A finished arena is frozen (its state stops changing), so its final metrics are those of the
    step that ended it. Not jitted here; jit the caller.

    Args:
      env: the env (no auto-reset).
      policies: team -> `(obs, rng) -> int32 [A]` for one arena; vmapped over arenas here.
      rng: key; arena i is reset from `jax.random.split(reset_key, num_episodes)[i]`.
      num_episodes: B, the number of arenas.
      record: also return poses [max_steps + 1, B, N, 3] and active [max_steps + 1, B, N] of
        every step (steps after an arena ended repeat its final state).

    Returns:
      The batched final state [B], and with `record` the trajectory dict.
    """
    reset_rng, play_rng = jax.random.split(rng)
    state = jax.vmap(env.reset)(jax.random.split(reset_rng, num_episodes))
    max_steps = env.config.max_steps

    def act(s: State, key: jax.Array) -> dict[str, jax.Array]:
        keys = dict(zip(TEAMS, jax.random.split(key, len(TEAMS)), strict=True))
        return {
            t: jax.vmap(policies[t])(s.obs[t], jax.random.split(keys[t], num_episodes)).astype(
                jnp.int32
            )
            for t in TEAMS
        }

    def advance(s: State, key: jax.Array) -> State:
        new = jax.vmap(env.step)(s, act(s, key))
        finished = s.done > 0

        def keep(old, nxt):
            mask = finished.reshape(finished.shape + (1,) * (nxt.ndim - 1))
            return jnp.where(mask, old, nxt)

        return jax.tree.map(keep, s, new)

    def pose_of(s: State) -> tuple[jax.Array, jax.Array]:
        w = s.world
        return jnp.concatenate([w.pos, w.yaw[..., None]], axis=-1), w.active

    if record:

        def scan_step(s, key):
            s = advance(s, key)
            return s, pose_of(s)

        keys = jax.random.split(play_rng, max_steps)
        final, (poses, active) = jax.lax.scan(scan_step, state, keys)
        p0, a0 = pose_of(state)
        traj = {
            "poses": jnp.concatenate([p0[None], poses]),
            "active": jnp.concatenate([a0[None], active]),
        }
        return final, traj

    def cond(carry):
        s, _, i = carry
        return (i < max_steps) & ~jnp.all(s.done > 0)

    def body(carry):
        s, key, i = carry
        key, sub = jax.random.split(key)
        return advance(s, sub), key, i + 1

    final, _, _ = jax.lax.while_loop(cond, body, (state, play_rng, jnp.zeros((), jnp.int32)))
    return final
