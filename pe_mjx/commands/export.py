"""`pe-mjx export`: one team's policy of a run as a self-contained StableHLO file."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Literal

import tyro

from pe_mjx import outputs
from pe_mjx.commands.common import check_new_file, fail
from pe_mjx.config import PresetName


@dataclasses.dataclass(frozen=True)
class ExportArgs:
    """Write one team's policy of a run as a self-contained file: StableHLO through `jax.export`
    (the greedy policy, normaliser and parameters folded in), run by
    pe_mjx/policy/export_loader.py with only jax and numpy, e.g. on a robot's computer (README,
    "Running a policy on robots")."""

    run: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
    """A `pe-mjx train` run directory or a shipped policy's name (mix-20-5-8)."""
    output: Annotated[Path, tyro.conf.arg(aliases=("-o",))] = Path("policy.jaxexport")
    """Where to write the policy file (a zip of policy.stablehlo and meta.json)."""
    team: Literal["pursuer", "evader"] = "pursuer"
    """Which of the run's policies to export."""
    preset: PresetName | None = None
    """Scene whose counts fix the input shapes; smaller scenes are padded by the loader (default:
    the run's own scene; 4-2-2 is the paper's robot setup)."""
    force: bool = False
    """Overwrite an existing output file."""


def run_export(args: ExportArgs) -> None:
    check_new_file("--output", args.output, args.force)
    from pe_mjx.config import get_preset
    from pe_mjx.policy.export import export_policy, write_policy
    from pe_mjx.policy.store import CheckpointError

    config = None if args.preset is None else get_preset(args.preset)
    try:
        program, info = export_policy(args.run, args.team, config)
    except CheckpointError as err:
        fail(str(err))
    try:  # through pe_mjx.outputs: the target is checked again (a device node) before the rename
        with outputs.writing(args.output, force=args.force, flag="--output") as tmp:
            size = write_policy(tmp, program, info)
    except OSError as err:
        fail(f"cannot write {args.output}: {err}")
    counts = ", ".join(f"{n} {k}" for k, n in info["counts"].items())
    print(f"wrote {args.output} ({size:,} bytes): the {args.team} policy of {args.run} ({counts})")
