"""pe_mjx.stages.geometry: shared offsets and distances, angle helpers, per-agent constants."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from pe_mjx.config import get_preset
from pe_mjx.stages.geometry import (
    cos_sin,
    drop_diagonal,
    geometry,
    per_agent,
    same_team,
    wrap_angle,
)
from tests.conftest import SMALL


def test_cos_sin_within_float32_rounding():
    a = np.linspace(-4 * math.pi, 4 * math.pi, 10001, dtype=np.float32)
    c, s = (np.asarray(x) for x in cos_sin(jnp.asarray(a)))
    np.testing.assert_allclose(c, np.cos(a.astype(np.float64)), atol=1.2e-7 * 4)
    np.testing.assert_allclose(s, np.sin(a.astype(np.float64)), atol=1.2e-7 * 4)


def test_wrap_angle_and_drop_diagonal():
    np.testing.assert_allclose(
        np.asarray(wrap_angle(jnp.asarray([3 * math.pi / 2, -3 * math.pi / 2, 0.5]))),
        [-math.pi / 2, math.pi / 2, 0.5],
        atol=1e-6,
    )
    x = jnp.arange(9).reshape(3, 3)
    np.testing.assert_array_equal(np.asarray(drop_diagonal(x)), [[1, 2], [3, 5], [6, 7]])


def test_per_agent_constants_pursuers_first():
    cfg = get_preset(SMALL)  # 2 pursuers (r 0.1), 1 evader (r 0.15)
    np.testing.assert_allclose(per_agent(cfg, "radius"), [0.1, 0.1, 0.15])
    np.testing.assert_array_equal(
        same_team(cfg), [[True, True, False], [True, True, False], [False, False, True]]
    )


def test_geometry_by_hand():
    # agent 0 at (1, 0) facing +y; agent 1 at (1, 1) straight ahead of it; one obstacle at (0, 0)
    pos = jnp.asarray([[1.0, 0.0], [1.0, 1.0]])
    yaw = jnp.asarray([math.pi / 2, 0.0])
    g = geometry(pos, yaw, jnp.asarray([[0.0, 0.0, 0.3]]))
    np.testing.assert_allclose(np.asarray(g.dist), [[0, 1], [1, 0]], atol=1e-6)
    np.testing.assert_allclose(np.asarray(g.norm), [1, math.sqrt(2)], atol=1e-6)
    np.testing.assert_allclose(np.asarray(g.obs_dist)[:, 0], [1, math.sqrt(2)], atol=1e-6)
    # in agent 0's heading frame (forward = +y, left = -x): agent 1 is 1 m ahead, the origin
    # (and the obstacle) 1 m to its left
    np.testing.assert_allclose([g.hx[0, 1], g.hy[0, 1]], [1, 0], atol=1e-6)
    np.testing.assert_allclose([g.origin_hx[0], g.origin_hy[0]], [0, 1], atol=1e-6)
    np.testing.assert_allclose([g.obs_hx[0, 0], g.obs_hy[0, 0]], [0, 1], atol=1e-6)
    # agent 1 faces +x: agent 0 is 1 m to its right
    np.testing.assert_allclose([g.hx[1, 0], g.hy[1, 0]], [0, -1], atol=1e-6)
    np.testing.assert_allclose(np.asarray(g.cos**2 + g.sin**2), 1, atol=1e-6)
