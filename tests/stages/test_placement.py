"""pe_mjx.stages.placement: a fresh arena keeps every clearance, and one key gives one arena."""

from __future__ import annotations

import jax
import numpy as np

from pe_mjx.config import get_preset
from pe_mjx.stages.geometry import per_agent
from pe_mjx.stages.placement import place


def test_place_keeps_clearance_and_is_deterministic():
    cfg = get_preset("4-1-2")
    a = cfg.arena
    placed = jax.jit(place, static_argnums=0)(cfg, jax.random.key(3))
    assert bool(placed.ok)
    obstacles, pos = np.asarray(placed.obstacles), np.asarray(placed.pos)
    assert obstacles.shape == (a.num_obstacles, 3) and pos.shape == (cfg.num_agents, 2)
    assert np.all(
        (obstacles[:, 2] >= a.obstacle_radius_min) & (obstacles[:, 2] <= a.obstacle_radius_max)
    )
    centres = np.concatenate([obstacles[:, :2], pos])
    radii = np.concatenate([obstacles[:, 2], per_agent(cfg, "radius")])
    assert np.all(np.linalg.norm(centres, axis=1) + radii <= a.radius - a.spawn_clearance + 1e-5)
    gap = np.linalg.norm(centres[:, None] - centres[None], axis=-1) - radii[:, None] - radii
    np.fill_diagonal(gap, np.inf)
    assert gap.min() >= a.spawn_clearance - 1e-5
    yaw = np.asarray(placed.yaw)
    assert np.all((yaw >= -np.pi) & (yaw < np.pi))
    again = jax.jit(place, static_argnums=0)(cfg, jax.random.key(3))
    np.testing.assert_array_equal(np.asarray(again.pos), pos)
