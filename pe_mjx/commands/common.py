"""What every subcommand checks before it works, each failure one line `pe-mjx: error: ...`."""

from __future__ import annotations

import contextlib
import io
import os
import re
import sys
from pathlib import Path
from typing import NoReturn

from pe_mjx.config import PRESETS
from pe_mjx.eval_config import SEED_LIMIT
from pe_mjx.names import BACKENDS

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def printable(text: str) -> str:
    """`text` with its control characters escaped as Python writes them (a file name holding a
    newline shows as `new\\nline`), so that a message stays one line."""
    return _CONTROL.sub(lambda found: repr(found.group())[1:-1], text)


def fail(message: str) -> NoReturn:
    """Ends the command with one error line and exit code 2."""
    print(f"pe-mjx: error: {printable(message)}", file=sys.stderr)
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
        if existing.is_symlink():  # a link to nothing, or a loop: mkdir fails on it at the end
            fail(f"{flag}: {existing} is a symbolic link to a missing directory (or a loop)")
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


def check_jax_platforms() -> None:
    """JAX can start the platform that JAX_PLATFORMS names, if it names one: a typo, or "cuda"
    on a machine without a GPU, was JAX's traceback from inside the first array made."""
    wanted = os.environ.get("JAX_PLATFORMS", "").strip()
    if not wanted:
        return
    import jax

    if jax.distributed.is_initialized():  # a group's processes start their backends together
        return
    try:
        jax.devices()
    except Exception as err:  # RuntimeError, or a bare AssertionError for "cuda" without CUDA
        why = " ".join(str(err).split())[:200] or type(err).__name__
        fail(f"JAX_PLATFORMS={wanted}: JAX cannot start it ({why}); unset it or name cpu")


def never_unencodable(stream: object) -> None:
    """Text the stream's encoding cannot write (a file name that is not UTF-8, "±" under
    PYTHONIOENCODING=ascii) is written escaped: a strict stream raised UnicodeEncodeError on the
    last line of a command whose outputs were already written."""
    if getattr(stream, "errors", None) == "strict":
        with contextlib.suppress(AttributeError, ValueError, io.UnsupportedOperation):
            stream.reconfigure(errors="backslashreplace")  # type: ignore[attr-defined]
