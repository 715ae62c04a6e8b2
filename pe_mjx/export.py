"""Standalone MJCF of the arena that `env.reset` draws for a seed (what `pe-mjx scene` writes)."""

from __future__ import annotations

import jax
import numpy as np

from pe_mjx.config import EnvConfig, get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.scene import Layout, scene_xml


def arena_layout(config: str | EnvConfig, seed: int) -> Layout:
    """The layout of `env.reset(jax.random.key(seed))`; placement is backend-independent."""
    config = get_preset(config) if isinstance(config, str) else config
    env = PursuitEvasionEnv(config, backend="kinematic")
    state = jax.jit(env.reset)(jax.random.key(seed))
    poses = env.poses(state)
    return Layout(
        pursuer=np.asarray(poses["pursuer"]),
        evader=np.asarray(poses["evader"]),
        obstacles=np.asarray(env.obstacles(state)),
    )


def arena_xml(config: str | EnvConfig, seed: int) -> str:
    config = get_preset(config) if isinstance(config, str) else config
    return scene_xml(config, arena_layout(config, seed))
