"""Offsets and distances a step computes once for events, rewards, observations and masks.

Also the small angle and frame helpers the other stages share, and the per-agent constants
(radii, speed limits, team membership) drawn from the config.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from pe_mjx.config import EnvConfig


def wrap_angle(a: jax.Array) -> jax.Array:
    """Angle(s) wrapped into [-pi, pi)."""
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


def cos_sin(a: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(cos a, sin a), within 1.2e-7 of `jnp.cos` / `jnp.sin` (float32 rounding).

    XLA's CPU backend evaluates cos and sin as scalar library calls (about 4 ns per element) and
    re-evaluates them inside each fused pairwise or per-action loop that reads the heading; these
    vectorised multiply-adds cost a fifth of that (the kinematic step ran ~1.2x faster with them).
    Cody-Waite reduction to [-pi/4, pi/4], then Cephes' sinf / cosf minimax polynomials.
    """
    k = jnp.round(a * (2 / np.pi))  # quadrant
    r = a - k * 1.5703125 - k * 4.837512969970703125e-4 - k * 7.54978995489188216e-8
    r2 = r * r
    sin_r = r + r * r2 * (-1.6666654611e-1 + r2 * (8.3321608736e-3 - r2 * 1.9515295891e-4))
    cos_r4 = 4.166664568298827e-2 + r2 * (-1.388731625493765e-3 + r2 * 2.443315711809948e-5)
    cos_r = 1 - 0.5 * r2 + r2 * r2 * cos_r4
    q = k.astype(jnp.int32) & 3
    swap = (q & 1) == 1
    cos = jnp.where(swap, sin_r, cos_r) * jnp.where((q == 1) | (q == 2), -1.0, 1.0)
    sin = jnp.where(swap, cos_r, sin_r) * jnp.where(q >= 2, -1.0, 1.0)
    return cos, sin


def to_heading(
    c: jax.Array, s: jax.Array, x: jax.Array, y: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """World vector (x, y) in the heading frame whose yaw has cosine c and sine s."""
    return c * x + s * y, -s * x + c * y


def bearing(x: jax.Array, y: jax.Array, d: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(cos, sin) of the direction of (x, y), whose length is d; (1, 0) when d = 0."""
    safe = jnp.where(d > 0, d, 1.0)
    return jnp.where(d > 0, x / safe, 1.0), jnp.where(d > 0, y / safe, 0.0)


def drop_diagonal(x: jax.Array) -> jax.Array:
    """[A, A, ...] -> [A, A - 1, ...]: row i without its entry i, order kept (no gather)."""
    a, rest = x.shape[0], x.shape[2:]
    flat = x.reshape((a * a, *rest))[1:]  # the diagonal entries now end each row of A + 1
    return flat.reshape((a - 1, a + 1, *rest))[:, :a].reshape((a, a - 1, *rest))


def per_agent(config: EnvConfig, attr: str) -> np.ndarray:
    """float32 [N]: a `TeamConfig` attribute (e.g. "radius", "max_speed") per agent."""
    p, e = config.pursuer.num_agents, config.evader.num_agents
    values = [getattr(config.pursuer, attr)] * p + [getattr(config.evader, attr)] * e
    return np.asarray(values, dtype=np.float32)


def same_team(config: EnvConfig) -> np.ndarray:
    """bool [N, N]: agents i and j are on the same team (the diagonal included)."""
    p, e = config.pursuer.num_agents, config.evader.num_agents
    is_pursuer = np.arange(p + e) < p
    return is_pursuer[:, None] == is_pursuer[None, :]


@struct.dataclass
class Geometry:
    """Offsets and distances from each agent i (row) of one arena; N agents, K obstacles.

    World frame: to agent j `dx`, `dy`, `dist` [N, N]; to obstacle k `obs_dx`, `obs_dy`,
    `obs_dist` [N, K]; from the arena centre `norm` [N]. Heading frame of agent i: `cos`, `sin`
    [N] of its yaw, the same offsets rotated into it, `hx`, `hy` [N, N] and `obs_hx`, `obs_hy`
    [N, K], and the offset to the world origin, `origin_hx`, `origin_hy` [N].
    """

    dx: jax.Array
    dy: jax.Array
    dist: jax.Array
    obs_dx: jax.Array
    obs_dy: jax.Array
    obs_dist: jax.Array
    norm: jax.Array
    cos: jax.Array
    sin: jax.Array
    hx: jax.Array
    hy: jax.Array
    obs_hx: jax.Array
    obs_hy: jax.Array
    origin_hx: jax.Array
    origin_hy: jax.Array


def geometry(pos: jax.Array, yaw: jax.Array, obstacles: jax.Array) -> Geometry:
    """The `Geometry` of positions [N, 2], headings [N] and obstacles [K, 3] (x, y, radius)."""
    x, y = pos[:, 0], pos[:, 1]
    c, s = cos_sin(yaw)
    # Renormalised (the polynomials' |(c, s)| is 1 within 1e-7). The division also keeps XLA
    # from fusing, i.e. re-evaluating, the polynomials into every pairwise and per-action loop
    # that reads them: it materialises (c, s) once instead (1.15x faster step on CPU).
    norm = jnp.sqrt(c**2 + s**2)
    c, s = c / norm, s / norm
    dx, dy = x[None, :] - x[:, None], y[None, :] - y[:, None]
    obs_dx, obs_dy = obstacles[None, :, 0] - x[:, None], obstacles[None, :, 1] - y[:, None]
    hx, hy = to_heading(c[:, None], s[:, None], dx, dy)
    obs_hx, obs_hy = to_heading(c[:, None], s[:, None], obs_dx, obs_dy)
    origin_hx, origin_hy = to_heading(c, s, -x, -y)
    return Geometry(
        dx=dx,
        dy=dy,
        dist=jnp.sqrt(dx**2 + dy**2),
        obs_dx=obs_dx,
        obs_dy=obs_dy,
        obs_dist=jnp.sqrt(obs_dx**2 + obs_dy**2),
        norm=jnp.sqrt(x**2 + y**2),
        cos=c,
        sin=s,
        hx=hx,
        hy=hy,
        obs_hx=obs_hx,
        obs_hy=obs_hy,
        origin_hx=origin_hx,
        origin_hy=origin_hy,
    )


__all__ = [
    "Geometry",
    "bearing",
    "cos_sin",
    "drop_diagonal",
    "geometry",
    "per_agent",
    "same_team",
    "to_heading",
    "wrap_angle",
]
