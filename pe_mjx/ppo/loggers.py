"""Where a training run reports: the progress bar's columns, TensorBoard (a writer that writes
nothing on processes other than 0), Weights & Biases, and notes on stderr."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rich.progress import BarColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from pe_mjx.experiment import ExperimentConfig
from pe_mjx.ppo.curves import CurveLog


def progress_columns() -> list[Any]:
    """The training bar: env steps done of the budget, speed, last success vs scripted, times."""
    return [
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed:,}/{task.total:,} env-steps"),
        TextColumn("{task.fields[speed]}"),
        TextColumn("{task.fields[success]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    ]


class NoWriter:
    """The TensorBoard writer of a process other than 0 in a group: it writes nothing."""

    def add_scalar(self, *args: Any) -> None:
        pass

    def close(self) -> None:
        pass


@contextlib.contextmanager
def closing(writer: Any, wandb_run: Any, curves: CurveLog | None) -> Iterator[None]:
    """Closes the TensorBoard writer and the W&B run, and writes the curves, however the block
    ends."""
    try:
        yield
    finally:
        writer.close()
        if curves is not None:
            curves.flush()
        if wandb_run is not None:
            wandb_run.finish()


def note(message: str) -> None:
    """One line on stderr, for runs without the progress bar (logs, `--no-progress`)."""
    print(message, file=sys.stderr, flush=True)


def import_wandb() -> Any:
    """The `wandb` module (ValueError without the extra)."""
    try:
        import wandb
    except ImportError:
        raise ValueError(
            "--wandb-project needs Weights & Biases: pip install 'pe-mjx[wandb]'"
        ) from None
    return wandb


def start_wandb(project: str, run_dir: Path, config: ExperimentConfig) -> Any:
    """A Weights & Biases run logging beside TensorBoard (ValueError without the extra)."""
    return import_wandb().init(
        project=project,
        name=run_dir.name,
        dir=str(run_dir),
        config=config.to_dict(),
        resume="allow",
    )
