"""Shared fixtures: compiled envs are cached for the whole session to keep XLA compiles few.

`compiled(config_or_name, backend)` returns a `Compiled` whose jitted functions are created once
per (config, backend) and compile lazily on first use, so a test that only needs `step` never pays
for the batched variants. Tests that need another config (max_steps, capture radius, ...) build it
with `EnvConfig.replace` and get their own cache entry.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx import env as pe_env
from pe_mjx.config import EnvConfig, get_preset

# Small preset used by the hand-placed rule tests: arena radius 2 m, 2 pursuers, 1 evader,
# 1 obstacle. Action indices (index = n_v * N_omega + n_omega):
SMALL = "2-1-1"
P_STOP = 6  # pursuer v = 0, omega = 0
P_FULL = 2 * 13 + 6  # pursuer v = 0.2 m/s, omega = 0
E_STOP = 9  # evader v = 0, omega = 0
E_FULL = 4 * 19 + 9  # evader v = 0.4 m/s, omega = 0


@jax.jit
def first(tree):
    """Element 0 of every leaf (one compile per tree layout instead of one eager op per leaf)."""
    return jax.tree.map(lambda x: x[0], tree)


@jax.jit
def pair(tree):
    """Two copies of every leaf, stacked on a new batch axis."""
    return jax.tree.map(lambda x: jnp.stack([x, x]), tree)


class Compiled:
    """An env and its jitted entry points (each compiles on first call).

    `step` runs the batched step (`batch_step`, which the contract test compiles for every preset)
    on two copies of the state and returns the first: one XLA compile less per env.
    """

    def __init__(self, config: EnvConfig, backend: str):
        self.env = pe_env.PursuitEvasionEnv(config, backend=backend)
        self.config = config
        self.backend = backend
        self.reset_to = jax.jit(self.env.reset_to)
        self.batch_reset = jax.jit(jax.vmap(self.env.reset))
        self.batch_step = jax.jit(jax.vmap(self.env.step))

    def step(self, state: pe_env.State, actions: dict[str, jax.Array]) -> pe_env.State:
        return first(self.batch_step(pair(state), pair(actions)))

    def reset(self, seed: int) -> pe_env.State:
        """`env.reset(jax.random.key(seed))`, through the batched reset."""
        return first(self.batch_reset(jnp.stack([jax.random.key(seed), jax.random.key(seed + 1)])))

    def actions(self, pursuer, evader) -> dict[str, jax.Array]:
        """Action dict; scalars are broadcast to the whole team."""
        p = np.broadcast_to(np.asarray(pursuer, np.int32), (self.env.num_pursuers,))
        e = np.broadcast_to(np.asarray(evader, np.int32), (self.env.num_evaders,))
        return {"pursuer": jnp.asarray(p), "evader": jnp.asarray(e)}

    def place(self, pursuer, evader, obstacles) -> pe_env.State:
        k = self.env.num_obstacles
        return self.reset_to(
            jnp.asarray(np.asarray(pursuer, np.float32)),
            jnp.asarray(np.asarray(evader, np.float32)),
            jnp.asarray(np.asarray(obstacles, np.float32).reshape(k, 3)),
        )


def sample_actions(rng: np.random.Generator, obs: dict) -> dict[str, jax.Array]:
    """Uniform over each agent's valid actions, in numpy (works with or without a batch axis)."""
    out = {}
    for team in ("pursuer", "evader"):
        mask = np.asarray(obs[team]["action_mask"])
        score = rng.uniform(0.5, 1.0, mask.shape) * mask  # 0 where invalid
        out[team] = jnp.asarray(np.argmax(score, axis=-1).astype(np.int32))
    return out


@functools.cache
def _compiled(config: EnvConfig, backend: str) -> Compiled:
    return Compiled(config, backend)


def compiled(config: str | EnvConfig, backend: str) -> Compiled:
    config = get_preset(config) if isinstance(config, str) else config
    return _compiled(config, backend)


@pytest.fixture(scope="session")
def get_compiled():
    """Session-wide factory: get_compiled(preset_or_config, backend) -> Compiled (cached)."""
    return compiled


def small_config(**changes) -> EnvConfig:
    """The 2-1-1 preset with top-level fields replaced."""
    return get_preset(SMALL).replace(**changes)


def small_with(**sub) -> EnvConfig:
    """The 2-1-1 preset with nested fields replaced: small_with(reward={"capture_distance": .4})."""
    cfg = get_preset(SMALL)
    changes = {k: dataclasses.replace(getattr(cfg, k), **v) for k, v in sub.items()}
    return cfg.replace(**changes)


def variant_config() -> EnvConfig:
    """2-1-1 with every optional rule switched on, shared by several tests (one compile):

    * capture_radius = 0.3 m (epsilon > r_p + r_e: capture without contact),
    * reward.capture_distance = 0.4 m (d_cap > epsilon: the floor of f_p is reachable),
    * min_turning_radius 0.3 m (pursuers) and 0.5 m (evaders),
    * max_steps = 2 (quick truncation for the auto-reset wrapper).
    """
    cfg = small_with(
        reward={"capture_distance": 0.4},
        pursuer={"min_turning_radius": 0.3},
        evader={"min_turning_radius": 0.5},
    )
    return cfg.replace(capture_radius=0.3, max_steps=2)


def fc(gap: float, rc: float = -10.0, danger: float = 0.2) -> float:
    """Paper's f_c, written independently of the package."""
    if gap <= 0:
        return rc
    if gap <= danger:
        return rc * (danger - gap) / (danger + gap)
    return 0.0


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
