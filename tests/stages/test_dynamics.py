"""pe_mjx.stages.dynamics: the action tables (paper eq. (2)), commands and the kinematic arc.

The MJX integrator against the kinematic one: tests/test_env.py and tests/test_rules.py.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.stages.dynamics import action_table, commands, integrate_kinematic
from tests.conftest import E_FULL, E_STOP, P_FULL, P_STOP, SMALL

TEAMS = ("pursuer", "evader")


def test_action_table_is_paper_eq2():
    cfg = get_preset("20-5-8")
    for team in TEAMS:
        t = cfg.team(team)
        v, w = action_table(t)
        speeds = np.linspace(0, t.max_speed, t.num_speeds)
        rates = np.linspace(-t.max_turn_rate, t.max_turn_rate, t.num_turn_rates)
        for n_v in range(t.num_speeds):
            for n_w in range(t.num_turn_rates):
                i = n_v * t.num_turn_rates + n_w
                assert v[i] == pytest.approx(speeds[n_v]) and w[i] == pytest.approx(rates[n_w])
    v, w = action_table(cfg.pursuer)
    assert (v[P_STOP], w[P_STOP]) == (0, pytest.approx(0, abs=1e-7))
    assert (v[P_FULL], w[P_FULL]) == (pytest.approx(0.2), pytest.approx(0, abs=1e-7))
    v, w = action_table(cfg.evader)
    assert (v[E_STOP], w[E_STOP]) == (0, pytest.approx(0, abs=1e-7))
    assert (v[E_FULL], w[E_FULL]) == (pytest.approx(0.4), pytest.approx(0, abs=1e-7))


def test_commands_clamp_count_and_stop_inactive():
    cfg = get_preset(SMALL)
    n_p = cfg.pursuer.num_actions
    actions = {"pursuer": jnp.asarray([-1, n_p + 5]), "evader": jnp.asarray([E_FULL])}
    cmd = commands(cfg, actions, jnp.asarray([True, True, False]))
    assert float(cmd.invalid_actions) == 2.0
    v, w = action_table(cfg.pursuer)
    np.testing.assert_allclose(np.asarray(cmd.speed), [v[0], v[-1], 0.0])
    np.testing.assert_allclose(np.asarray(cmd.turn), [w[0], w[-1], 0.0])


def test_kinematic_arc_by_hand():
    cfg = get_preset(SMALL)
    dt = cfg.control_dt
    v, omega = 0.2, (math.pi / 2) / dt  # a quarter turn of radius v / omega
    m = integrate_kinematic(
        cfg,
        jnp.asarray([[0.0, 0.0], [1.0, 1.0]]),
        jnp.asarray([0.0, math.pi / 2]),
        jnp.asarray([v, v]),
        jnp.asarray([omega, 0.0]),
    )
    r = v / omega
    np.testing.assert_allclose(np.asarray(m.pos), [[r, r], [1.0, 1.0 + v * dt]], atol=1e-6)
    np.testing.assert_allclose(np.asarray(m.yaw), [math.pi / 2, math.pi / 2], atol=1e-6)
    np.testing.assert_allclose(np.asarray(m.vel), [[0, v], [0, v]], atol=1e-6)
