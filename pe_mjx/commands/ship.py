"""`pe-mjx ship RUN NAME`: a run's checkpoint as a policy-only copy (`pe_mjx.policy.ship`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro


@dataclasses.dataclass(frozen=True)
class ShipArgs:
    """Ship one checkpoint of a `pe-mjx train` run as a packaged policy (pe_mjx/assets/policies;
    with --dest, DEST/NAME instead): its config and policy parameters only, so it plays
    (`pe-mjx view/evaluate --pursuers NAME`) but cannot be resumed. --nearest-k and
    --length-unit ship the same parameters reading their neighbours differently (no training);
    such a copy of a packed policy, into the directory that holds it, shares its parameters file
    (a few kB; it plays while that file is unchanged)."""

    run: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
    """The run directory."""
    name: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="NAME")]
    """The shipped policy's name (e.g. mlp-20-5-8)."""
    step: int | None = None
    """Checkpoint step (iteration) to ship; default the latest."""
    replace: bool = False
    """Replace a shipped policy of that name."""
    dest: Path | None = None
    """Write to DEST/NAME rather than into the package (pe_mjx/assets/policies)."""
    nearest_k: int | None = None
    """Ship with local attention: both teams' networks read only the k nearest entities of each
    type (the parameters are the run's, unchanged)."""
    length_unit: float | None = None
    """Ship reading neighbour distances in units of this many metres, in any arena (the
    parameters are the run's, unchanged)."""
    resumable: bool = False
    """Instead of a policy, write DEST/NAME (--dest required) as the copy of a run in progress to
    commit: its config, curves and the learners of its checkpoint (no arenas, no policies);
    `pe-mjx train --resume DEST/NAME` continues the run (train/README.md)."""


def run_ship(args: ShipArgs) -> None:
    if args.resumable:
        return _ship_resumable(args)
    from pe_mjx.policy.ship import ship_policy

    path, meta = ship_policy(
        args.run,
        args.name,
        step=args.step,
        replace=args.replace,
        dest=args.dest,
        nearest_k=args.nearest_k,
        length_unit=args.length_unit,
    )
    print(f"shipped {args.run} step {meta['step']} ({meta['env_steps']:,} env steps) as {path}")


def _ship_resumable(args: ShipArgs) -> None:
    from pe_mjx.policy.ship import check_name
    from pe_mjx.ppo.resumable import write_resumable_copy

    if args.dest is None:
        raise ValueError("--resumable needs --dest (e.g. --dest train/unfinished)")
    if args.nearest_k is not None or args.length_unit is not None:
        raise ValueError("--resumable copies the run as it trains: no --nearest-k, --length-unit")
    check_name(args.name)
    target = args.dest / args.name
    meta = write_resumable_copy(args.run, target, step=args.step, replace=args.replace)
    print(
        f"wrote a resumable copy of {args.run} step {meta['step']} ({meta['env_steps']:,} env "
        f"steps) to {target}: continue it with `pe-mjx train --resume {target}`"
    )
