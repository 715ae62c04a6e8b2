"""Resumable copies of a run in progress: what `pe-mjx ship RUN NAME --resumable` writes.

A *resumable copy* is what a run in progress commits to git between sessions: its config, curves
and one checkpoint holding only the learners (parameters, optimiser and normaliser state), the
RNG and the counters, without the arenas in flight (about 60% of a train state at 20-5-8) or the
policy items. `--resume` on it (`pe_mjx.ppo.checkpoint`, which reads it back) continues exactly
for the learners and draws the arenas afresh (a warning line says so): the episodes in flight at
the cut are lost, nothing that was learned.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from pe_mjx import outputs
from pe_mjx.ppo.checkpoint import CheckpointError, read_host_state, resumable_meta, save_learners
from pe_mjx.ppo.curves import curves_file


def write_resumable_copy(
    run_dir: str | Path, target: str | Path, step: int | None = None, replace: bool = False
) -> dict[str, Any]:
    """Writes `target`, the copy of run `run_dir` to commit while it is in progress: its
    `config.json` and curves, and checkpoint `step` (default: the latest) with the learners,
    RNG and counters only (module docstring). `pe-mjx train --resume TARGET` (or a copy of it
    back under `runs/`) continues the run. Built beside `target` and renamed once; returns the
    checkpoint's metadata. A `ValueError` (an existing target without `replace`) or a
    `CheckpointError` before anything is written."""
    run_dir, target = Path(run_dir), Path(target)
    _check_target(run_dir, target, replace)
    meta = resumable_meta(run_dir, step)
    if not (run_dir / "config.json").is_file():
        raise CheckpointError(f"{run_dir} has no config.json: it is not a training run")
    state = read_host_state(run_dir, meta)
    target.parent.mkdir(parents=True, exist_ok=True)
    outputs.clean_stale(target.parent)  # the temporaries of copies killed midway
    stage = outputs.temp_path(target, keep_suffix=False)
    stage.mkdir()
    try:
        for name in ("config.json", curves_file(run_dir).name):
            if (run_dir / name).is_file():
                shutil.copy2(run_dir / name, stage / name)
        save_learners(stage, state, meta)
        if target.exists():  # replace
            shutil.rmtree(target)
        os.replace(stage, target)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return meta


def _check_target(run_dir: Path, target: Path, replace: bool) -> None:
    """A `ValueError` when `target` cannot take the copy: a file, an existing copy without
    `replace`, the run itself or a directory inside it (or holding it)."""
    if target.exists() and not target.is_dir():
        raise ValueError(f"{target} exists and is not a directory: refused")
    if target.exists() and not replace:
        raise ValueError(f"{target} exists (--replace to replace it)")
    source, dest = run_dir.resolve(), target.resolve()
    if dest == source or dest in source.parents or source in dest.parents:
        raise ValueError(f"{target} holds the run or lies inside it: choose another --dest")
