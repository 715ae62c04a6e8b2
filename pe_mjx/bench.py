"""What the benchmarks in tools/ share: best-of-n timing of a jitted call and the machine's
description for their JSON reports.

It lives in the package, not in tools/, because a tool imports only the installed package (no
tool imports another, no `sys.path` edits), and these few lines are the same in every benchmark:
one definition of "how fast" keeps their numbers comparable.
"""

from __future__ import annotations

import datetime
import os
import platform
import time
from collections.abc import Callable
from typing import Any, NamedTuple


class Timing(NamedTuple):
    first: float
    """Seconds of the first call (compilation included)."""
    wall: float
    """Best wall seconds per call over the repeats."""
    cpu: float
    """Best CPU seconds per call (all threads of this process) over the repeats."""


def best_of(fn: Callable[..., Any], *args: Any, repeats: int) -> Timing:
    """Times `fn(*args)` (waited for with `jax.block_until_ready`) once, then `repeats` times.

    Best-of-`repeats` rather than the median, and CPU time next to wall time, because on a
    shared machine both depend on what else runs; on an idle machine wall time is at most the
    CPU time."""
    import jax

    tic = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - tic
    wall, cpu = [], []
    for _ in range(repeats):
        tic, cpu_tic = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn(*args))
        wall.append(time.perf_counter() - tic)
        cpu.append(time.process_time() - cpu_tic)
    return Timing(first, min(wall, default=float("inf")), min(cpu, default=float("inf")))


def machine() -> dict[str, Any]:
    """The machine a benchmark ran on, as its report records it."""
    import jax

    return {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
        "jax": jax.__version__,
        "devices": [str(d) for d in jax.devices()],
        "date": datetime.date.today().isoformat(),
    }
