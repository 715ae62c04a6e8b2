"""What every subcommand checks before it works, each failure one line `pe-mjx: error: ...`."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import NoReturn

from pe_mjx.config import PRESETS
from pe_mjx.eval_config import SEED_LIMIT
from pe_mjx.names import BACKENDS


def fail(message: str) -> NoReturn:
    """Ends the command with one error line and exit code 2."""
    print(f"pe-mjx: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def check_preset(name: str) -> None:
    if name not in PRESETS:
        fail(f"--preset: unknown preset {name!r}; known presets: {', '.join(PRESETS)}")


def check_seed(seed: int) -> None:
    if not 0 <= seed < SEED_LIMIT:
        fail(f"--seed must be in [0, 2**32), got {seed}")


def check_backend(backend: str) -> None:
    if backend not in BACKENDS:
        fail(f"--backend: unknown backend {backend!r}; expected {' or '.join(BACKENDS)}")


def check_writable_dir(flag: str, directory: Path) -> None:
    """`directory` is, or can be created as, a writable directory."""
    existing = directory
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        fail(f"{flag}: {existing} is not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        fail(f"{flag}: {existing} is not writable")


def check_new_file(flag: str, path: Path, force: bool) -> None:
    """`path` can be written as a new file (an existing regular file only with --force; never a
    directory, device node, FIFO or socket): `pe_mjx.outputs.check_target`."""
    from pe_mjx import outputs

    try:
        outputs.check_target(path, force=force, flag=flag)
    except outputs.OutputError as err:
        fail(str(err))


def one_line(err: BaseException, limit: int = 300) -> str:
    """A library's message (which may span many lines) as one line of at most `limit`."""
    text = " ".join(str(err).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
