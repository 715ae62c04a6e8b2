"""`pe-mjx rate`: a leaderboard of a scene's pursuer and evader policies from cross-play results
(`pe_mjx.ratings`), written as OUT/leaderboard.md and OUT/leaderboard.json."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Annotated

import tyro

from pe_mjx import outputs
from pe_mjx.commands.common import check_new_file, check_writable_dir, fail, one_line


@dataclasses.dataclass(frozen=True)
class RateArgs:
    """Rate every pursuer and every evader policy of one scene from the results.json files of
    `pe-mjx evaluate` (or reproduce), without playing: Bradley-Terry, P(an evader is
    incapacitated) = sigmoid(pursuer rating - evader rating), one match per evader per trial,
    intervals by a bootstrap over arenas. Writes OUT/leaderboard.md and OUT/leaderboard.json."""

    results: Annotated[
        tuple[Path, ...], tyro.conf.Positional, tyro.conf.arg(metavar="RESULTS.json")
    ]
    """results.json files of one scene and backend; a pairing that two files of the same seed
    and trial count both hold (the same arenas) counts once, from the first."""
    out: Path
    """Directory for leaderboard.md and leaderboard.json (created if missing)."""
    anchor: str = "scripted"
    """The evader policy rated 0 (by its name in the leaderboard)."""
    level: float = 0.95
    """Confidence level of the intervals."""
    resamples: int = 1000
    """Bootstrap resamples of the arenas."""
    seed: int = 0
    """Seed of the bootstrap."""
    force: bool = False
    """Overwrite an existing leaderboard in OUT."""


def run_rate(args: RateArgs) -> None:
    from pe_mjx import ratings

    targets = (args.out / "leaderboard.md", args.out / "leaderboard.json")
    try:
        ratings.check_options(args.level, args.resamples, args.seed)
    except ValueError as err:
        fail(str(err))
    check_writable_dir("--out", args.out)
    if args.out.is_dir():  # refused before the files are read and rated, not after
        for target in targets:
            check_new_file("--out", target, args.force)
    try:
        matches = ratings.read_results(args.results)
        board = ratings.leaderboard(matches, args.anchor, args.level, args.resamples, args.seed)
    except ValueError as err:
        fail(one_line(err))
    markdown = ratings.to_markdown(board)
    args.out.mkdir(parents=True, exist_ok=True)
    outputs.write_file(targets[0], markdown, force=args.force, flag="--out")
    payload = json.dumps(ratings.to_json(board), indent=1, allow_nan=False)
    outputs.write_file(targets[1], payload + "\n", force=args.force, flag="--out")
    print(markdown, end="")
    print(f"wrote {targets[0]} and {targets[1]}")
