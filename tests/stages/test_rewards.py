"""pe_mjx.stages.rewards: f_c, the named terms, the flee shaping and a team's total."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from pe_mjx.config import get_preset
from pe_mjx.names import REWARD_TERMS
from pe_mjx.stages.geometry import geometry
from pe_mjx.stages.rewards import (
    collision_reward,
    flee_term,
    paper_terms,
    reward_terms,
    team_rewards,
    zero_terms,
)
from tests.conftest import SMALL, fc

CFG = get_preset(SMALL)


@pytest.mark.parametrize("gap", [-0.1, 0.0, 0.05, 0.2, 0.3])
def test_collision_reward_is_the_papers_fc(gap):
    assert float(collision_reward(jnp.asarray(gap), -10.0, 0.2)) == pytest.approx(fc(gap))


def test_terms_are_the_named_ones_and_the_total_their_sum():
    zero = zero_terms(CFG)
    assert {t: tuple(v) for t, v in zero.items()} == REWARD_TERMS
    pos = jnp.asarray([[0.0, 0.5], [0.0, -0.5], [1.0, 0.0]])
    obstacles = jnp.asarray([[0.0, -1.4, 0.3]])
    active = jnp.ones(3, dtype=bool)
    g = geometry(pos, jnp.zeros(3), obstacles)
    terms = reward_terms(CFG, g, pos, pos, active, active, jnp.zeros((2, 1), bool), obstacles)
    assert {t: set(v) for t, v in terms.items()} == {t: set(v) for t, v in REWARD_TERMS.items()}
    rc = CFG.reward
    d = np.linalg.norm(np.asarray(pos[:2] - pos[2]), axis=-1)
    np.testing.assert_allclose(np.asarray(terms["pursuer"]["pursuit"]), rc.pursuit_scale / d)
    valid = {"pursuer": jnp.asarray([True, False]), "evader": jnp.asarray([True])}
    total = team_rewards(terms, valid)
    want = sum(np.asarray(terms["pursuer"][n]) for n in REWARD_TERMS["pursuer"])
    np.testing.assert_allclose(np.asarray(total["pursuer"]), [want[0], 0.0], rtol=1e-6)


def test_flee_pays_for_moving_away_from_the_nearest_pursuer():
    active = jnp.ones(3, dtype=bool)
    old = jnp.asarray([[0.0, 0.0], [1.5, 0.0], [0.5, 0.0]])
    new = old.at[2].set(jnp.asarray([0.7, 0.0]))  # 0.2 m further from pursuer 0
    assert float(flee_term(CFG, old, new, active)[0]) == 0.0  # off in the presets
    cfg = CFG.replace(reward=dataclasses.replace(CFG.reward, evader_flee=10.0, flee_range=5.0))
    assert float(flee_term(cfg, old, new, active)[0]) == pytest.approx(10 * 0.2, rel=1e-5)


def test_pursuit_nearest_sums_the_shaping_over_the_k_nearest_active_evaders():
    base = get_preset("8-2-4")
    cfg = base.replace(
        pursuer=dataclasses.replace(base.pursuer, num_agents=4),
        evader=dataclasses.replace(base.evader, num_agents=3),
        arena=dataclasses.replace(base.arena, num_obstacles=0),
    )
    p = cfg.pursuer.num_agents
    pursuers = [[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [-2.0, -2.0]]
    evaders = [[0.5, 0.0], [0.0, 1.0], [-1.5, 0.0]]  # 0.5, 1.0 and 1.5 m from pursuer 0
    pos = jnp.asarray([*pursuers, *evaders])
    g = geometry(pos, jnp.zeros(7), jnp.zeros((0, 3)))
    active = jnp.ones(7, dtype=bool).at[p + 0].set(False)  # the nearest evader is down
    none = jnp.zeros((p, 3), bool)

    def pursuit(k):
        c = cfg.replace(reward=dataclasses.replace(cfg.reward, pursuit_nearest=k))
        return np.asarray(paper_terms(c, g, active, none, jnp.zeros((0, 3)))["pursuer"]["pursuit"])

    d = np.linalg.norm(np.asarray(pos[:p, None] - pos[None, p:]), axis=-1)
    f = np.where(np.asarray(active[p:])[None], cfg.reward.pursuit_scale / d, 0.0)
    np.testing.assert_allclose(pursuit(None), f.sum(1), rtol=1e-6)  # the paper's: every evader
    np.testing.assert_allclose(pursuit(3), f.sum(1), rtol=1e-6)  # k >= E: the same
    np.testing.assert_allclose(pursuit(1), f.max(1), rtol=1e-6)
    # Pursuer 0's nearest evader is down: its k = 1 term is the one at 1 m.
    assert pursuit(1)[0] == pytest.approx(cfg.reward.pursuit_scale / 1.0, rel=1e-6)
    np.testing.assert_allclose(pursuit(2), np.sort(f, 1)[:, 1:].sum(1), rtol=1e-6)
