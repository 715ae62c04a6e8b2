"""Ratings from cross-play results: one Bradley-Terry rating per pursuer and per evader policy of
a scene, with bootstrap intervals, read from `pe-mjx evaluate` results.json files (`pe-mjx rate`).
P(the pursuers win a match: one evader of one trial) = sigmoid(pursuer rating - evader rating),
the anchor (by default the scripted evader) at 0. The model, the fit and the intervals: `model`;
reading and combining results.json files: `results`; the leaderboard and its files: `board`.

    from pe_mjx import ratings
    board = ratings.leaderboard(ratings.read_results(["results.json"]))
    print(ratings.to_markdown(board))
"""

from pe_mjx.ratings.board import Leaderboard, leaderboard, to_json, to_markdown
from pe_mjx.ratings.model import ELO_PER_UNIT, PRIOR_SD, Pairing, Rating, check_options, rate
from pe_mjx.ratings.results import Matches, policy_name, read_results

__all__ = [
    "ELO_PER_UNIT",
    "PRIOR_SD",
    "Leaderboard",
    "Matches",
    "Pairing",
    "Rating",
    "check_options",
    "leaderboard",
    "policy_name",
    "rate",
    "read_results",
    "to_json",
    "to_markdown",
]
