"""A scene's leaderboard (`leaderboard`): the ratings of every policy of its results, written as
JSON-ready data (`to_json`) and as a markdown page (`to_markdown`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from pe_mjx.ratings.model import ELO_PER_UNIT, PRIOR_SD, Rating, rate
from pe_mjx.ratings.results import Matches


@dataclasses.dataclass(frozen=True)
class Leaderboard:
    """One scene's ratings, each team best first, and how they were rated."""

    scene: str
    backend: str
    pursuers: tuple[Rating, ...]
    evaders: tuple[Rating, ...]
    anchor: str
    level: float
    resamples: int
    seed: int
    sources: tuple[dict[str, Any], ...] = ()


def leaderboard(
    matches: Matches,
    anchor: str = "scripted",
    level: float = 0.95,
    resamples: int = 1000,
    seed: int = 0,
) -> Leaderboard:
    """The ratings of every policy of `matches` (see `rate`)."""
    pursuers, evaders = rate(matches.pairings, anchor, level, resamples, seed, matches.labels)
    return Leaderboard(
        matches.scene,
        matches.backend,
        pursuers,
        evaders,
        anchor,
        level,
        resamples,
        seed,
        matches.sources,
    )


def _finite(x: float) -> float | None:
    """JSON has no infinity or NaN: an open end or an undefined spread is null."""
    return float(x) if math.isfinite(x) else None


def to_json(board: Leaderboard) -> dict[str, Any]:
    """The leaderboard as JSON-ready data (an open interval end is null)."""

    def row(rank: int, r: Rating) -> dict[str, Any]:
        return {
            "rank": rank,
            "name": r.name,
            "label": r.label,
            "rating": r.rating,
            "low": _finite(r.low),
            "high": _finite(r.high),
            "se": _finite(r.se),
            "elo": r.elo,
            "matches": r.matches,
            "won": r.won,
            "win_rate": r.won / r.matches,
            "opponents": r.opponents,
            "bound": r.bound,
        }

    return {
        "scene": board.scene,
        "backend": board.backend,
        "model": {
            "kind": "bradley-terry",
            "match": "one evader of one trial; the pursuers win it if the evader is incapacitated",
            "p_pursuers_win": "sigmoid(pursuer rating - evader rating)",
            "anchor": f"evader {board.anchor} = 0",
            "prior_sd": PRIOR_SD,
            "interval": "percentile bootstrap over arenas (the trials of a seed)",
            "level": board.level,
            "resamples": board.resamples,
            "seed": board.seed,
            "elo_per_unit": ELO_PER_UNIT,
        },
        "sources": list(board.sources),
        "pursuers": [row(i + 1, r) for i, r in enumerate(board.pursuers)],
        "evaders": [row(i + 1, r) for i, r in enumerate(board.evaders)],
    }


_MARKS = {"two-sided": "", "won every match": "†", "lost every match": "†", "unbounded": "‡"}


def _cell(r: Rating | None, anchor: str) -> list[str]:
    if r is None:
        return ["", "", ""]
    if r.team == "evader" and r.name == anchor:
        rating = "0 (anchor)"
    else:
        low = "(-∞" if math.isinf(r.low) else f"[{r.low:.2f}"
        high = "∞)" if math.isinf(r.high) else f"{r.high:.2f}]"
        rating = f"{r.rating:.2f}{_MARKS[r.bound]} {low}, {high}"
    return [f"`{r.name}`", rating, f"{r.won:,} / {r.matches:,}"]


def _source_line(source: dict[str, Any]) -> str:
    """One file of a leaderboard: what it held and which of its pairings an earlier file had."""
    count = source["pairings"]
    line = (
        f"- `{source['path']}`: {count} pairing{'s' if count != 1 else ''} of "
        f"{source['trials']} trials, seed {source['seed']}"
    )
    before = source["counted_before"]
    same = sum(d["same_games"] for d in before)
    if before:
        games = [f"{same} the same games"] if same else []
        games += [f"{len(before) - same} other games"] if len(before) > same else []
        line += f" ({len(before)} counted from an earlier file, same arenas: {', '.join(games)})"
    return line


def to_markdown(board: Leaderboard) -> str:
    """The leaderboard as a markdown page: one table, pursuers and evaders side by side."""
    matches = sum(r.matches for r in board.pursuers)
    level = f"{100 * board.level:g}%"
    lines = [
        f"# Leaderboard of {board.scene} ({board.backend} backend)",
        "",
        f"Bradley-Terry ratings from {matches:,} matches (one match: one evader of one trial, won "
        "by the pursuers if that evader is incapacitated): P(pursuers win) = sigmoid(pursuer "
        f"rating - evader rating); the {board.anchor} evader is 0. {level} intervals: percentile "
        f"bootstrap over arenas ({board.resamples:,} resamples, seed {board.seed}). Written by "
        "`pe-mjx rate` (pe_mjx/ratings/).",
        "",
        f"| # | Pursuer | Rating [{level}] | Won / matches "
        f"| Evader | Rating [{level}] | Won / matches |",
        "|---|---|---|---|---|---|---|",
    ]
    a = board.anchor
    for i in range(max(len(board.pursuers), len(board.evaders))):
        p = board.pursuers[i] if i < len(board.pursuers) else None
        e = board.evaders[i] if i < len(board.evaders) else None
        lines.append("| " + " | ".join([str(i + 1), *_cell(p, a), *_cell(e, a)]) + " |")
    bounds = {r.bound for r in (*board.pursuers, *board.evaders)}
    if bounds & {"won every match", "lost every match"}:
        lines += [
            "",
            "† Won or lost every match: no finite estimate (the rating shown is the prior's); "
            "the interval's finite end is the rating at which that record has probability "
            f"{(1 - board.level) / 2:g}, however correlated the outcomes of one arena are.",
        ]
    if "unbounded" in bounds:
        lines += ["", "‡ Beat, or lost to, every policy outside its group: not bounded."]
    lines += ["", "Sources:", ""]
    lines += [_source_line(source) for source in board.sources]
    return "\n".join(lines) + "\n"
