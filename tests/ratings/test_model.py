"""The Bradley-Terry fit (`pe_mjx.ratings.model`): synthetic matches drawn from known strengths,
the bootstrap's spread, the boundary cases (a record of all wins or all losses, an anchor that
links nothing) and the invariances (anchor, names, order)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import expit, log_expit

from pe_mjx.ratings import model
from pe_mjx.ratings.model import Pairing

PURSUERS = {"p-strong": 2.0, "p-good": 1.0, "p-fair": 0.0, "p-weak": -1.0}
EVADERS = {"e-strong": 1.5, "e-fair": 0.5, "scripted": 0.0, "e-weak": -1.0}
"""True ratings of the synthetic policies: the scripted evader (the anchor) is 0."""


def simulate(
    rng: np.random.Generator,
    pursuers: dict[str, float] = PURSUERS,
    evaders: dict[str, float] = EVADERS,
    trials: int = 200,
    per_trial: int = 5,
    shared: float = 0.5,
) -> list[Pairing]:
    """Every pursuer against every evader, `trials` trials of `per_trial` evaders, each evader
    incapacitated with probability sigmoid(r_p - r_e) exactly. Outcomes are correlated as in a
    real evaluation: trial t of every pairing plays arena t, and each evader's outcome uses,
    with probability `shared`, that arena's uniform draw instead of its own (the marginal
    probability is unchanged; two evaders of a trial correlate by `shared`**2)."""
    arena = rng.random(trials)
    pairings = []
    for p, r_p in pursuers.items():
        for e, r_e in evaders.items():
            own = rng.random((trials, per_trial))
            draw = np.where(rng.random((trials, per_trial)) < shared, arena[:, None], own)
            captured = (draw < expit(r_p - r_e)).sum(axis=1)
            pairings.append(Pairing(p, e, captured, per_trial, "seed 0"))
    return pairings


def by_name(rows) -> dict[tuple[str, str], model.Rating]:
    return {(r.team, r.name): r for r in rows}


def true_ratings() -> dict[tuple[str, str], float]:
    return {
        **{("pursuer", n): r for n, r in PURSUERS.items()},
        **{("evader", n): r for n, r in EVADERS.items()},
    }


def test_synthetic_matches_recover_the_known_strengths():
    """16 pairings of 1,000 matches each (200 trials of 5 evaders), correlated within arenas.
    Each rating then rests on 4,000 matches and has a bootstrap standard error of 0.05 to 0.1;
    the true ratings of a team are at least 0.5 apart, 5 standard errors of a difference at
    the least: the order comes out right for any seed but with a probability below 1e-6.

    Each true rating must lie within 5 bootstrap standard errors of its estimate (a miss has
    probability about 6e-7 per rating for an estimator that is normal, unbiased and whose
    bootstrap spread is right, which `test_the_bootstrap_spread_is_the_sampling_spread`
    checks; over 25 seeds the largest miss was 2.3 standard errors). The 95% intervals
    themselves cannot be checked rating by rating with overwhelming probability: each misses
    5% of the time by design, so one of 7 would miss for 30% of seeds; they are checked to
    span about 1.96 standard errors on either side."""
    pursuers, evaders = model.rate(simulate(np.random.default_rng(7)), resamples=300)
    assert [r.name for r in pursuers] == list(PURSUERS)
    assert [r.name for r in evaders] == list(EVADERS)
    for key, truth in true_ratings().items():
        row = by_name((*pursuers, *evaders))[key]
        if key == ("evader", "scripted"):
            assert (row.rating, row.low, row.high, row.se) == (0.0, 0.0, 0.0, 0.0)
            continue
        assert row.bound == "two-sided" and row.matches == 4 * 1000
        assert 0.02 < row.se < 0.2, row
        assert abs(row.rating - truth) < 5 * row.se, (key, row.rating, truth, row.se)
        assert row.low < row.rating < row.high
        assert row.high - row.low == pytest.approx(2 * 1.96 * row.se, rel=0.35)


def test_the_bootstrap_spread_is_the_sampling_spread():
    """The bootstrap over arenas gives each rating the spread its estimate really has. 150
    independent synthetic evaluations (strongly correlated: `shared` 0.7) give the true spread
    to about 6%; one evaluation's bootstrap (300 resamples) must match it within a factor 1.6.
    Over 8 seeds tried (56 ratios), the log of that ratio had a standard deviation of 0.10:
    the factor is 4.7 of them, and a miss has probability about 1e-5 over the 7 ratings.
    Treating the matches as independent (the inverse Fisher information) gave the pursuers 0.4
    to 0.6 of their true spread here, so this test fails for intervals that ignore arenas."""
    rng = np.random.default_rng(11)
    estimates = []
    for _ in range(150):
        pursuers, evaders = model.rate(simulate(rng, shared=0.7), resamples=10)
        rows = by_name((*pursuers, *evaders))
        estimates.append([rows[key].rating for key in true_ratings()])
    spread = np.std(estimates, axis=0, ddof=1)
    pursuers, evaders = model.rate(simulate(rng, shared=0.7), resamples=300)
    rows = by_name((*pursuers, *evaders))
    for i, key in enumerate(true_ratings()):
        if key != ("evader", "scripted"):
            assert 1 / 1.6 < rows[key].se / spread[i] < 1.6, (key, rows[key].se, spread[i])


def _unbeaten_pairings() -> list[Pairing]:
    """The synthetic pairings with an extra pursuer that incapacitated every evader it met."""
    pairings = simulate(np.random.default_rng(3), trials=100)
    for e in ("e-fair", "scripted"):
        pairings.append(Pairing("p-perfect", e, np.full(100, 5), 5, "seed 0"))
    return pairings


def test_a_policy_that_won_every_match_gets_a_finite_rating_and_a_one_sided_interval():
    """No finite maximum-likelihood estimate exists for it: the prior keeps its rating finite
    (and first), its interval is open above, and its lower end is where winning all 100 arenas
    (each once, against its strongest opponent there) has probability 2.5%."""
    pairings = _unbeaten_pairings()
    pursuers, evaders = model.rate(pairings, resamples=50)
    rows = by_name((*pursuers, *evaders))
    best = pursuers[0]
    assert best.name == "p-perfect" and best.bound == "won every match"
    assert math.isfinite(best.rating) and best.rating > pursuers[1].rating
    assert best.high == math.inf and math.isnan(best.se) and best.won == best.matches == 1000
    strongest = max(rows["evader", "e-fair"].rating, rows["evader", "scripted"].rating)
    assert 100 * log_expit(best.low - strongest) == pytest.approx(math.log(0.025), abs=1e-6)
    assert best.low < best.rating
    # It tells nothing about the others: their ratings hardly move without it.
    without = by_name(sum(model.rate(pairings[:-2], resamples=10), ()))
    for key, row in without.items():
        assert abs(rows[key].rating - row.rating) < 0.05, key


def test_a_policy_that_lost_every_match_is_the_mirror_image():
    pairings = simulate(np.random.default_rng(4), trials=100)
    for p in ("p-good", "p-fair"):
        pairings.append(Pairing(p, "e-hopeless", np.full(100, 5), 5, "seed 0"))
    pursuers, evaders = model.rate(pairings, resamples=50)
    worst = evaders[-1]
    assert worst.name == "e-hopeless" and worst.bound == "lost every match"
    assert worst.low == -math.inf and math.isfinite(worst.rating) and worst.rating < worst.high
    weakest = min(r.rating for r in pursuers if r.name in ("p-good", "p-fair"))
    assert 100 * log_expit(weakest - worst.high) == pytest.approx(math.log(0.025), abs=1e-6)


def test_the_anchor_is_zero_and_another_anchor_shifts_every_rating():
    """Ratings are fixed up to a shift: naming another anchor shifts all by its rating (up to
    the prior's pull toward the anchor, well under 0.01 here)."""
    pairings = simulate(np.random.default_rng(5), trials=100)
    first = by_name(sum(model.rate(pairings, resamples=10), ()))
    other = by_name(sum(model.rate(pairings, anchor="e-fair", resamples=10), ()))
    assert first["evader", "scripted"].rating == 0.0 == other["evader", "e-fair"].rating
    shift = first["evader", "e-fair"].rating
    for key, row in first.items():
        assert other[key].rating == pytest.approx(row.rating - shift, abs=0.01), key


def test_relabelling_and_reordering_change_nothing():
    """Names and the order of the pairings are labels: renamed and shuffled, every policy keeps
    its rating and its interval (the bootstrap draws arenas, whatever the names)."""
    pairings = simulate(np.random.default_rng(6), trials=100)
    rename = {n: f"z-{i}" for i, n in enumerate([*PURSUERS, *EVADERS])} | {"scripted": "scripted"}
    order = np.random.default_rng(0).permutation(len(pairings))
    renamed = [
        Pairing(
            rename[pairings[i].pursuer],
            rename[pairings[i].evader],
            pairings[i].captured,
            5,
            "seed 0",
        )
        for i in order
    ]
    first = by_name(sum(model.rate(pairings, resamples=40), ()))
    second = by_name(sum(model.rate(renamed, resamples=40), ()))
    for (team, name), row in first.items():
        again = second[team, rename[name]]
        assert again.rating == pytest.approx(row.rating, abs=1e-7)
        assert (again.low, again.high) == pytest.approx((row.low, row.high), abs=1e-6)


def test_ratings_that_nothing_links_are_refused():
    linked = simulate(np.random.default_rng(8), trials=20)
    apart = [Pairing("a-other", "e-other", np.full(20, 2), 5, "seed 0")]  # sorts first
    with pytest.raises(ValueError, match="pursuer a-other, evader e-other: no chain of pairings"):
        model.rate(linked + apart, resamples=10)
    swept = [Pairing("p-strong", "scripted", np.full(20, 5), 5, "seed 0")]
    with pytest.raises(ValueError, match="--anchor: the scripted evader shares no cycle"):
        model.rate(swept, resamples=10)
    with pytest.raises(ValueError, match="--anchor: no evader policy 'nobody'"):
        model.rate(linked, anchor="nobody", resamples=10)
    with pytest.raises(ValueError, match="--resamples"):
        model.rate(linked, resamples=1)


def test_more_policies_than_a_fit_can_take_are_refused_before_anything_is_allocated(monkeypatch):
    """A crafted results.json of 40,000 policies (35 MB) asked for two dense 13 GB matrices."""
    many = [Pairing(f"p{i}", "scripted", np.array([0, 1]), 1, "seed 0") for i in range(1001)]
    with pytest.raises(ValueError, match="1,002 policies to rate, more than the 1,000"):
        model.rate(many, resamples=10)
    monkeypatch.setenv("PE_MJX_MEMORY_BYTES", "1000")
    with pytest.raises(ValueError, match=r"RESULTS.json \(16 pairings of 8 policies\): their fits"):
        model.rate(simulate(np.random.default_rng(0), trials=5), resamples=10)
