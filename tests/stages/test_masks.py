"""pe_mjx.stages.masks: the turning-radius mask, the mask table and the look-ahead mask."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from pe_mjx.config import get_preset
from pe_mjx.stages.dynamics import action_table
from pe_mjx.stages.geometry import geometry
from pe_mjx.stages.masks import action_mask, mask_table, stop_actions, turning_mask
from tests.conftest import P_STOP, SMALL, variant_config

CFG = get_preset(SMALL)


def pursuer_mask(cfg, x: float, y: float, yaw: float, obstacle=(0.0, -1.4, 0.3)):
    """The mask of one pursuer at (x, y) heading `yaw`, alone with one obstacle."""
    obstacles = jnp.asarray([obstacle])
    g = geometry(jnp.asarray([[x, y]]), jnp.asarray([yaw]), obstacles)
    table = mask_table(cfg, "pursuer")
    return np.asarray(
        action_mask(cfg, table, g.origin_hx, g.origin_hy, g.obs_hx, g.obs_hy, obstacles)
    )[0]


def test_mask_table_sizes():
    t = mask_table(CFG, "pursuer")
    team = CFG.pursuer
    moving = team.num_actions - team.num_turn_rates
    assert t.num_stop == team.num_turn_rates and t.num_points == CFG.mask_points
    assert t.x.shape == t.y.shape == t.sq.shape == (moving * CFG.mask_points,)
    np.testing.assert_allclose(t.sq, t.x**2 + t.y**2, rtol=1e-6)
    assert t.allowed.all() and t.stop.sum() == team.num_turn_rates  # no turning radius


def test_open_space_allows_everything_and_the_wall_masks_forward_moves():
    assert pursuer_mask(CFG, 0.0, 0.5, 0.0).all()
    # 3 mm from the wall, facing it: every forward move is masked, the stop actions are not
    mask = pursuer_mask(CFG, 1.897, 0.0, 0.0)
    v, _ = action_table(CFG.pursuer)
    assert mask[v == 0].all() and not mask[v > 0].all()
    # facing away from the wall: moving straight on is allowed
    mask = pursuer_mask(CFG, 1.897, 0.0, math.pi)
    assert mask[np.argmax(v)]


def test_touching_leaves_only_the_stop_actions():
    mask = pursuer_mask(CFG, 0.0, -1.0, 0.0, obstacle=(0.0, -1.2, 0.3))
    np.testing.assert_array_equal(mask, stop_actions(CFG.pursuer))
    assert mask[P_STOP]


def test_turning_mask_by_hand():
    team = variant_config().pursuer  # min turning radius 0.3 m
    v, w = action_table(team)
    ok = turning_mask(team)
    with np.errstate(divide="ignore", invalid="ignore"):
        radius = np.where(np.abs(w) > 1e-9, v / np.abs(w), np.inf)
    np.testing.assert_array_equal(ok[v > 0], radius[v > 0] >= 0.3)
    assert ok[v == 0].sum() == 1  # standing still, not spinning
