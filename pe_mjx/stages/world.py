"""The game state of one arena (`World`), read and written by every stage."""

from __future__ import annotations

import jax
from flax import struct


@struct.dataclass
class World:
    """The game state, for all N agents (pursuers first) of one arena."""

    pos: jax.Array  # [N, 2] world x, y
    yaw: jax.Array  # [N] heading in [-pi, pi)
    vel: jax.Array  # [N, 2] world velocity at the end of the last step
    active: jax.Array  # bool [N]
    cause: jax.Array  # int32 [N], 0 while active, else the first incapacitation cause
    distance: jax.Array  # [N] distance travelled this episode (sum of per-step displacements)
    captures: jax.Array  # int32 [N]: pursuer -> evaders it captured; evader -> 1 if captured
    obstacles: jax.Array  # [K, 3] x, y, radius
    step: jax.Array  # int32 [] control steps taken this episode


__all__ = ["World"]
