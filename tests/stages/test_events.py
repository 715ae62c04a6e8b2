"""pe_mjx.stages.events: each cause on a hand-placed case, in SPEC 2.3's order.

2-1-1: arena radius 2 m, pursuers r 0.1, evader r 0.15, capture radius 0.25 m.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from pe_mjx.config import get_preset
from pe_mjx.names import CAPTURE, OBSTACLE, OPPONENT, TEAMMATE, WALL
from pe_mjx.stages.events import events
from pe_mjx.stages.geometry import geometry
from tests.conftest import SMALL

CFG = get_preset(SMALL)
FAR = [[0.0, -1.4, 0.3]]


def run(pos, obstacles=FAR, active=(True, True, True)):
    pos, obstacles = jnp.asarray(pos), jnp.asarray(obstacles)
    g = geometry(pos, jnp.zeros(3), obstacles)
    return events(CFG, g, jnp.asarray(active), obstacles)


def test_wall_obstacle_and_free():
    ev = run([[1.95, 0.0], [0.0, -1.0], [-1.0, 0.5]], obstacles=[[0.0, -1.2, 0.3]])
    np.testing.assert_array_equal(np.asarray(ev.cause), [WALL, OBSTACLE, 0])
    np.testing.assert_array_equal(np.asarray(ev.active), [False, False, True])
    assert not np.asarray(ev.capture_pairs).any()


def test_capture_counts_every_pursuer_within_eps():
    ev = run([[0.0, 0.2], [0.0, -0.2], [0.0, 0.0]], obstacles=FAR)
    np.testing.assert_array_equal(np.asarray(ev.cause), [CAPTURE, CAPTURE, CAPTURE])
    np.testing.assert_array_equal(np.asarray(ev.capture_pairs), [[True], [True]])
    np.testing.assert_array_equal(np.asarray(ev.new_captures), [1, 1, 1])


def test_touching_teammates_and_an_inactive_evader():
    # the pursuers touch each other; the evader, already down, touches nobody it could capture
    ev = run([[0.0, 0.0], [0.15, 0.0], [0.5, 0.5]], active=(True, True, False))
    np.testing.assert_array_equal(np.asarray(ev.cause), [TEAMMATE, TEAMMATE, 0])
    # a pursuer touching the downed evader (no capture: it is inactive) is an opponent collision
    ev = run([[0.0, 0.0], [1.0, 0.0], [0.2, 0.0]], active=(True, True, False))
    np.testing.assert_array_equal(np.asarray(ev.cause), [OPPONENT, 0, 0])
    assert not np.asarray(ev.active)[0] and np.asarray(ev.active)[1]
