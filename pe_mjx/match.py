"""Playing episodes with policies: a jittable `rollout` and the scripted demo match."""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp

from pe_mjx.config import TEAMS, get_preset
from pe_mjx.env import CAPTURE, CAUSE_NAMES, PursuitEvasionEnv, State
from pe_mjx.policies import Policy, make_policy


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

    def cond(carry):
        s, _ = carry
        return (s.world.step - start < steps) & (s.done == 0)

    def body(carry):
        s, key = carry
        key, *team_keys = jax.random.split(key, len(TEAMS) + 1)
        actions = {
            team: policies[team](s.obs[team], k) for team, k in zip(TEAMS, team_keys, strict=True)
        }
        return env.step(s, actions), key

    final, _ = jax.lax.while_loop(cond, body, (state, rng))
    return final


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
    out: dict[str, Any] = {"steps": int(w.step)}
    p = env.num_pursuers
    cause = {"pursuers": w.cause[:p], "evaders": w.cause[p:]}
    out["evaders_captured"] = int((cause["evaders"] == CAPTURE).sum())
    out["evaders_total"] = env.num_evaders
    out["pursuers_total"] = env.num_pursuers
    for who, codes in cause.items():
        for code, name in CAUSE_NAMES.items():
            out[f"{who}_{name}"] = int((codes == code).sum())
        out[f"{who}_active"] = int((codes == 0).sum())
    # SPEC 4: success counts every incapacitated evader (n'), captured or crashed.
    out["success_rate"] = (env.num_evaders - out["evaders_active"]) / env.num_evaders
    out["pursuit_cost"] = env.num_pursuers - out["pursuers_active"]
    out["mean_pursuer_distance"] = round(float(w.distance[:p].mean()), 4)
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


__all__ = ["match_summary", "play_scripted_match", "rollout"]
