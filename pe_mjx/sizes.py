"""Sizes checked before anything allocates: counts, batches and trials against the memory they
need, and values shown in error messages cut to a length.

Every estimate here is a lower bound (what the arrays must hold at the least; XLA's buffers take
several times more), compared with the memory this machine has available (`MemAvailable` of
/proc/meminfo, else `os.sysconf`; `PE_MJX_MEMORY_BYTES` states it instead, for tests and for a
machine whose accelerator has more memory than its host). A size that cannot fit is one line
naming the flag, in well under a second, instead of minutes in native code that ignore Ctrl-C
(`ppo.num_envs: 1000000000` in a config file stalled for 12 minutes and more).

Standard library only (the lowest layer).
"""

from __future__ import annotations

import math
import os
import reprlib
from typing import Any

FLOAT_BYTES = 4
"""float32: what the env's state, observations and rollouts hold."""


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (None: unknown); a `SizeError` if
    `PE_MJX_MEMORY_BYTES` states something that is not a number of bytes."""
    stated = os.environ.get("PE_MJX_MEMORY_BYTES")
    if stated is not None and stated.strip():
        try:
            number = float(stated)
        except ValueError:
            number = math.nan
        # A typo was ignored (and the machine's own memory used), "inf" was a traceback and
        # "-5" blamed the flag whose size then did not fit in 0 bytes.
        if not (math.isfinite(number) and number >= 1):
            raise SizeError(
                f"PE_MJX_MEMORY_BYTES must be a positive number of bytes (e.g. 64e9), got "
                f"{shorten(stated, 40)}; unset it to use this machine's memory"
            )
        return int(number)
    try:
        with open("/proc/meminfo", "rb") as f:
            for line in f.read(1 << 16).decode(errors="replace").splitlines():
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, AttributeError):
        return None


def human(n: float) -> str:
    """Bytes as "1.5 GB" (powers of 1000)."""
    for unit in ("bytes", "kB", "MB", "GB", "TB", "PB", "EB"):
        if abs(n) < 1000 or unit == "EB":
            return f"{n:,.0f} {unit}" if unit == "bytes" else f"{n:,.1f} {unit}"
        n /= 1000
    raise AssertionError("unreachable")


class SizeError(ValueError):
    """A size that cannot fit in memory: its message is the one line a user sees."""


def check_memory(flag: str, need: int, what: str) -> None:
    """A `SizeError` naming `flag` if `need` bytes (a lower bound, `what` says of what) exceed
    the memory available."""
    have = available_memory()
    if have is not None and need > have:
        raise SizeError(
            f"{flag}: {what} need at least {human(need)} of memory, more than the "
            f"{human(have)} available here; choose a smaller value"
        )


def arena_bytes(num_pursuers: int, num_evaders: int, num_obstacles: int) -> int:
    """A lower bound on the bytes of one arena's state and observations: every agent sees every
    other entity (one float32 per pair at the least)."""
    agents = num_pursuers + num_evaders
    return max(1, agents) * max(1, agents + num_obstacles) * FLOAT_BYTES


def _counts(env: Any) -> tuple[int, int, int]:
    return env.pursuer.num_agents, env.evader.num_agents, env.arena.num_obstacles


def check_scene(env: Any, flag: str = "--env") -> None:
    """One arena of `env` (an `EnvConfig`) fits in memory."""
    p, e, k = _counts(env)
    check_memory(f"{flag} ({p} pursuers, {e} evaders, {k} obstacles)", arena_bytes(p, e, k), "they")


def check_training(config: Any) -> None:
    """The arenas and rollouts an `ExperimentConfig` allocates fit in memory: `ppo.num_envs`
    arenas, each `ppo.unroll_length` steps of observations kept for the update, and
    `eval_envs` arenas for the evaluations."""
    check_scene(config.env)
    per_arena = arena_bytes(*_counts(config.env))
    ppo = config.ppo
    check_memory(
        f"ppo.num_envs {ppo.num_envs:,} x ppo.unroll_length {ppo.unroll_length:,}",
        ppo.num_envs * (ppo.unroll_length + 1) * per_arena,
        "the rollouts",
    )
    check_memory(f"eval_envs {config.eval_envs:,}", config.eval_envs * per_arena, "its arenas")


def check_evaluation(env: Any, trials: int, record: int, flag: str = "--trials") -> None:
    """A pairing's `trials` arenas (one batch) and its `record` recorded episodes (every step's
    poses) fit in memory."""
    check_scene(env)
    p, e, k = _counts(env)
    check_memory(f"{flag} {trials:,}", trials * arena_bytes(p, e, k), "its arenas")
    frame = (p + e) * 3 * FLOAT_BYTES  # a pose (x, y, heading) per agent
    check_memory(f"--record {record:,}", record * env.max_steps * frame, "the recorded episodes")


def check_recording(env: Any, arenas: int, steps: int, flag: str = "--steps") -> None:
    """`steps` recorded frames of `arenas` arenas (every agent's pose each step) fit in
    memory (`pe-mjx view --export`)."""
    p, e, _ = _counts(env)
    frame = arenas * (p + e) * 3 * FLOAT_BYTES
    check_memory(f"{flag} {steps:,}", steps * frame, "the recorded frames")


_REPR = reprlib.Repr()
_REPR.maxlevel = 3
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = 6
_REPR.maxstring = _REPR.maxother = 80
_REPR.maxlong = 40


def shorten(value: Any, limit: int = 120) -> str:
    """`repr(value)` for an error message, bounded: nested and long values are elided (reprlib,
    which visits a bounded part of them: a YAML alias bomb is never expanded), and the text is
    cut to `limit` characters."""
    try:
        text = _REPR.repr(value)
    except Exception:  # a value whose repr fails: its type is enough
        text = f"<{type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


__all__ = [
    "SizeError",
    "arena_bytes",
    "available_memory",
    "check_evaluation",
    "check_memory",
    "check_scene",
    "check_training",
    "human",
    "shorten",
]
