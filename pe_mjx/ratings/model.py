"""The Bradley-Terry model of cross-play: one rating per pursuer and per evader policy of a scene,
fitted to pairings of policies, with bootstrap intervals over arenas (`rate`).

The model. One *match* is one evader of one trial: the pursuer team wins it if that evader is
incapacitated when the episode ends (captured or crashed, as the success rate of SPEC 4 counts
it), the evader wins it if it is still active. A pursuer policy p and an evader policy e have
ratings r_p and r_e, and P(the pursuers win a match) = sigmoid(r_p - r_e). Per evader, because
the success rate, the paper's headline number, is the mean of exactly these outcomes, and it is
the finest outcome results.json keeps (the evaders incapacitated in each trial); a trial as one
match would throw the count away and need a threshold (all caught? most?).

The fit: maximum a posteriori with `scipy.optimize.minimize` (Newton-CG on the exact gradient
and Hessian, then plain Newton steps to 1e-9) under a normal prior N(0, `PRIOR_SD`^2) on every
rating but the anchor's: a ridge that keeps finite the rating of a policy that won (or lost)
every match, whose likelihood has no maximum. Elsewhere it shrinks a rating toward the anchor's
by a fraction of about 1 / (PRIOR_SD^2 x its Fisher information): under 0.1% for a policy with a
hundred matches at moderate odds. Ratings are fixed up to a shift; the *anchor*, by default the
scripted evader, is 0: a pursuer's rating is then the log-odds that it incapacitates a scripted
evader, and +1 multiplies the odds of winning a match by e. `elo` is the same number on Elo's
scale (400 / ln 10 per unit, the anchor at 0).

The intervals. The evaders of one trial are not independent matches (they share the pursuers,
the obstacles and one episode), and trial t of every pairing with the same seed and trial count
starts from the same arena. So the intervals are a percentile bootstrap over arenas: each
resample draws, for every group of pairings that share arenas, that many arenas with
replacement (one draw for the whole group), and refits; `resamples` resamples from a fixed
`seed`. Treating the matches as independent (the Fisher information) makes them too narrow: the
bootstrap's standard errors are a median 1.07 times those at 20-5-8 and 1.43 at 240-60-120 (60
evaders a trial), and up to 2.5 (tests/ratings/test_model.py checks the bootstrap's spread).

Separation. A policy that won every match has no finite estimate: the data bound its rating from
below only. Its interval is open above, and its lower end is the rating at which winning every
arena it played has probability (1 - level) / 2, each arena counted once against its strongest
opponent there (the most that correlated outcomes allow), its opponents at their estimates; its
rating is then the prior's, a point with no meaning of its own. A policy that lost every match
is the mirror image. A policy cut off from the anchor otherwise (a group that beat, or lost to,
everyone outside it) is unbounded on both sides.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

TEAMS = ("pursuer", "evader")
PRIOR_SD = 10.0
"""Standard deviation of the normal prior on every rating but the anchor's (logits)."""
ELO_PER_UNIT = 400 / math.log(10)
"""Elo points per unit of rating: a difference of 400 multiplies the odds by 10."""
MAX_RESAMPLES = 100_000
MAX_POLICIES = 1_000
"""Policies (both teams) one leaderboard rates at most: each resample refits them with a dense
[C, C] Hessian (1,000 take about half an hour at the default 1,000 resamples)."""


@dataclasses.dataclass(frozen=True)
class Pairing:
    """One pursuer policy against one evader policy over `len(captured)` trials."""

    pursuer: str
    evader: str
    captured: np.ndarray
    """int [T]: the evaders incapacitated in each trial (the matches the pursuers won)."""
    evaders: int
    """Evaders in each trial (matches per trial)."""
    arenas: str = ""
    """Trial t of pairings with equal `arenas` started from the same arena."""

    @property
    def matches(self) -> int:
        return len(self.captured) * self.evaders

    @property
    def wins(self) -> int:
        """Matches the pursuers won."""
        return int(np.sum(self.captured))


@dataclasses.dataclass(frozen=True)
class Rating:
    """One policy's row of a leaderboard."""

    team: str
    name: str
    rating: float
    low: float
    """Lower end of the interval (-inf: unbounded)."""
    high: float
    """Upper end of the interval (inf: unbounded)."""
    se: float
    """Standard deviation of the bootstrap ratings (NaN where the data bound one side only)."""
    matches: int
    won: int
    """Matches this policy won (a pursuer's: evaders incapacitated; an evader's: survived)."""
    opponents: int
    bound: str
    """"two-sided", "won every match", "lost every match", or "unbounded"."""
    label: str = ""

    @property
    def elo(self) -> float:
        return ELO_PER_UNIT * self.rating


class _Columns:
    """Every policy of the pairings as a column: pursuers first, then evaders, each sorted."""

    def __init__(self, pairings: Sequence[Pairing], anchor: str):
        self.names = {
            "pursuer": sorted({p.pursuer for p in pairings}),
            "evader": sorted({p.evader for p in pairings}),
        }
        self.keys = [(t, n) for t in TEAMS for n in self.names[t]]
        self.index = {key: i for i, key in enumerate(self.keys)}
        if ("evader", anchor) not in self.index:
            known = ", ".join(self.names["evader"])
            raise ValueError(
                f"--anchor: no evader policy {anchor!r} in the results; one of {known}"
            )
        self.anchor = self.index["evader", anchor]
        self.p = np.array([self.index["pursuer", x.pursuer] for x in pairings], dtype=int)
        self.e = np.array([self.index["evader", x.evader] for x in pairings], dtype=int)
        free = np.array([i for i in range(len(self.keys)) if i != self.anchor], dtype=int)
        self.design = np.zeros((len(pairings), len(self.keys)))
        self.design[np.arange(len(pairings)), self.p] = 1.0
        self.design[np.arange(len(pairings)), self.e] = -1.0
        self.design = self.design[:, free]
        self.free = free

    def full(self, theta: np.ndarray) -> np.ndarray:
        """Every column's rating [..., C] from the free ones [..., C - 1] (the anchor's is 0)."""
        out = np.zeros((*theta.shape[:-1], len(self.keys)))
        out[..., self.free] = theta
        return out


def _fit(design: np.ndarray, wins: np.ndarray, matches: np.ndarray, start: np.ndarray):
    """The MAP ratings [C - 1] of the free columns: maximises sum over pairings of
    wins log sigmoid(d) + (matches - wins) log sigmoid(-d), d = design @ theta, less the prior.
    `design` is [J, C - 1] (+1 pursuer, -1 evader), `wins` and `matches` are [J]."""
    from scipy import optimize, special

    precision = 1.0 / PRIOR_SD**2
    losses = matches - wins

    def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
        d = design @ theta
        value = wins @ np.logaddexp(0.0, -d) + losses @ np.logaddexp(0.0, d)
        grad = design.T @ (matches * special.expit(d) - wins) + precision * theta
        return float(value + 0.5 * precision * theta @ theta), grad

    def hessian(theta: np.ndarray) -> np.ndarray:
        p = special.expit(design @ theta)
        weights = matches * p * (1.0 - p)
        return design.T @ (design * weights[:, None]) + precision * np.eye(len(theta))

    # Newton steps (conjugate gradients on the exact Hessian); its line search may stop short on
    # float rounding near the optimum, where plain Newton steps then converge at once.
    found = optimize.minimize(objective, start, jac=True, hess=hessian, method="Newton-CG")
    theta = found.x
    for _ in range(4):
        step = np.linalg.solve(hessian(theta), objective(theta)[1])
        theta = theta - step
        if np.max(np.abs(step), initial=0.0) < 1e-9:
            return theta
    raise ValueError(f"the rating fit did not converge: {found.message}")


def _arena_groups(pairings: Sequence[Pairing]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Pairings that share arenas: per group, their indices [J_g] and captures [J_g, T_g]."""
    groups: dict[tuple[str, int], list[int]] = {}
    for j, pairing in enumerate(pairings):
        groups.setdefault((pairing.arenas, len(pairing.captured)), []).append(j)
    return [
        (np.array(js), np.stack([pairings[j].captured for j in js]).astype(float))
        for _, js in sorted(groups.items())
    ]


def _bootstrap(
    pairings: Sequence[Pairing], columns: _Columns, estimate: np.ndarray, resamples: int, seed: int
) -> np.ndarray:
    """The ratings [resamples, C] refitted to resampled arenas (see the module docstring)."""
    rng = np.random.default_rng(seed)
    groups = _arena_groups(pairings)
    matches = np.array([p.matches for p in pairings], dtype=float)
    out = np.empty((resamples, len(columns.free)))
    wins = np.empty(len(pairings))
    for b in range(resamples):
        for js, captured in groups:
            trials = captured.shape[1]
            drawn = rng.multinomial(trials, np.full(trials, 1.0 / trials))
            wins[js] = captured @ drawn
        out[b] = _fit(columns.design, wins, matches, estimate)
    return columns.full(out)


def _beats(pairings: Sequence[Pairing], columns: _Columns):
    """The directed graph [C, C] of "won a match against" between policies."""
    from scipy import sparse

    size = len(columns.keys)
    rows, cols = [], []
    for j, pairing in enumerate(pairings):
        p, e = columns.p[j], columns.e[j]
        if pairing.wins > 0:
            rows.append(p)
            cols.append(e)
        if pairing.wins < pairing.matches:
            rows.append(e)
            cols.append(p)
    return sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(size, size))


def _check_connected(pairings: Sequence[Pairing], columns: _Columns) -> np.ndarray:
    """The strongly connected component of every column in the "won against" graph; a
    ValueError if some policy shares no chain of pairings with the anchor, or if the anchor won
    or lost every match (then no other rating is bounded)."""
    from scipy.sparse import csgraph

    beats = _beats(pairings, columns)
    _, weak = csgraph.connected_components(beats, directed=True, connection="weak")
    home = weak[columns.anchor]
    apart = [f"{t} {n}" for (t, n), c in zip(columns.keys, weak, strict=True) if c != home]
    if apart:
        raise ValueError(
            f"{', '.join(apart[:4])}{' ...' if len(apart) > 4 else ''}: no chain of pairings "
            "links them to the anchor; rate those results apart"
        )
    _, strong = csgraph.connected_components(beats, directed=True, connection="strong")
    if np.sum(strong == strong[columns.anchor]) == 1:
        name = columns.keys[columns.anchor][1]
        raise ValueError(
            f"--anchor: the {name} evader shares no cycle of wins with another policy (it won, or "
            "lost, every match against each opponent): no rating relative to it is bounded; "
            "choose another --anchor"
        )
    return strong


def _record_bound(
    x: int,
    won_all: bool,
    pairings: Sequence[Pairing],
    columns: _Columns,
    ratings: np.ndarray,
    tail: float,
) -> float:
    """The finite end of the interval of column `x`, which won (`won_all`) or lost every match:
    the rating at which that record has probability `tail`, each arena counted once against the
    strongest (weakest) opponent it met there, the opponents at their `ratings`."""
    from scipy import optimize, special

    worst: dict[tuple[str, int], float] = {}
    pick = max if won_all else min
    for j, pairing in enumerate(pairings):
        p, e = columns.p[j], columns.e[j]
        if x in (p, e):
            other = float(ratings[e if x == p else p])
            key = (pairing.arenas, len(pairing.captured))
            worst[key] = pick(worst.get(key, other), other)
    trials = np.array([key[1] for key in worst], dtype=float)
    opponents = np.array(list(worst.values()))
    sign = 1.0 if won_all else -1.0

    def excess(r: float) -> float:  # log P(the record | r) - log(tail): monotone in r
        return float(trials @ special.log_expit(sign * (r - opponents))) - math.log(tail)

    low, high = opponents.min() - 1.0, opponents.max() + 1.0
    while sign * excess(low) > 0:
        low -= 2.0 * (high - low)
    while sign * excess(high) < 0:
        high += 2.0 * (high - low)
    return float(optimize.brentq(excess, low, high, xtol=1e-9))


def check_options(level: float, resamples: int, seed: int) -> None:
    if not 0.0 < level < 1.0:
        raise ValueError(f"--level must be in (0, 1), got {level}")
    if not 10 <= resamples <= MAX_RESAMPLES:
        raise ValueError(f"--resamples must be in 10..{MAX_RESAMPLES:,}, got {resamples}")
    if not 0 <= seed < 2**32:
        raise ValueError(f"--seed must be in [0, 2**32), got {seed}")


def check_size(pairings: Sequence[Pairing], resamples: int) -> None:
    """The policies and pairings fit one fit (`MAX_POLICIES`) and its arrays fit in memory: a
    ValueError naming the results, before anything is allocated. A crafted results.json of
    40,000 policies asked for two dense 13 GB matrices."""
    from pe_mjx import sizes

    count = len({p.pursuer for p in pairings}) + len({p.evader for p in pairings})
    if count > MAX_POLICIES:
        raise ValueError(
            f"RESULTS.json: {count:,} policies to rate, more than the {MAX_POLICIES:,} one "
            "leaderboard rates; rate fewer results files at once"
        )
    # The design [J, C] three times over (built, sliced, weighted) and the replicates [B, C].
    need = 8 * count * (3 * len(pairings) + resamples)
    sizes.check_memory(
        f"RESULTS.json ({len(pairings):,} pairings of {count:,} policies)", need, "their fits"
    )


def rate(
    pairings: Sequence[Pairing],
    anchor: str = "scripted",
    level: float = 0.95,
    resamples: int = 1000,
    seed: int = 0,
    labels: dict[tuple[str, str], str] | None = None,
) -> tuple[tuple[Rating, ...], tuple[Rating, ...]]:
    """The pursuers' and the evaders' ratings, each sorted best first (module docstring):
    the evader policy `anchor` is 0, intervals at `level` from `resamples` bootstrap resamples
    drawn from `seed`. A ValueError (one line) if the pairings leave a rating undefined."""
    check_options(level, resamples, seed)
    if not pairings:
        raise ValueError("no pairings to rate")
    check_size(pairings, resamples)
    columns = _Columns(pairings, anchor)
    strong = _check_connected(pairings, columns)
    wins = np.array([p.wins for p in pairings], dtype=float)
    matches = np.array([p.matches for p in pairings], dtype=float)
    theta = _fit(columns.design, wins, matches, np.zeros(len(columns.free)))
    ratings = columns.full(theta)
    replicates = _bootstrap(pairings, columns, theta, resamples, seed)
    tail = (1.0 - level) / 2.0
    lows, highs = np.quantile(replicates, [tail, 1.0 - tail], axis=0)
    spread = replicates.std(axis=0, ddof=1)
    played, won, opponents = _records(pairings, columns)
    rows: dict[str, list[Rating]] = {team: [] for team in TEAMS}
    for x, (team, name) in enumerate(columns.keys):
        low, high, se, bound = float(lows[x]), float(highs[x]), float(spread[x]), "two-sided"
        if strong[x] != strong[columns.anchor]:
            settled = all(strong[o] == strong[columns.anchor] for o in opponents[x])
            se, low, high, bound = math.nan, -math.inf, math.inf, "unbounded"
            if settled and won[x] == played[x]:
                bound = "won every match"
                low = _record_bound(x, True, pairings, columns, ratings, tail)
            elif settled and won[x] == 0:
                bound = "lost every match"
                high = _record_bound(x, False, pairings, columns, ratings, tail)
        rows[team].append(
            Rating(
                team=team,
                name=name,
                rating=float(ratings[x]),
                low=low,
                high=high,
                se=se,
                matches=int(played[x]),
                won=int(won[x]),
                opponents=len(opponents[x]),
                bound=bound,
                label=(labels or {}).get((team, name), ""),
            )
        )
    ordered = [tuple(sorted(rows[t], key=lambda r: (-r.rating, r.name))) for t in TEAMS]
    return ordered[0], ordered[1]


def _records(pairings: Sequence[Pairing], columns: _Columns):
    """Per column: matches played [C], matches won [C], and the set of its opponents' columns."""
    size = len(columns.keys)
    played, won = np.zeros(size, dtype=np.int64), np.zeros(size, dtype=np.int64)
    opponents: list[set[int]] = [set() for _ in range(size)]
    for j, pairing in enumerate(pairings):
        p, e = columns.p[j], columns.e[j]
        played[p] += pairing.matches
        played[e] += pairing.matches
        won[p] += pairing.wins
        won[e] += pairing.matches - pairing.wins
        opponents[p].add(e)
        opponents[e].add(p)
    return played, won, opponents
