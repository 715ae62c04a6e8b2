"""A run's compact learning curves: every scalar the trainer logs, one CSV row per log point.

`runs/NAME/curves.csv.xz` is the record that travels with a run (committed, read by `pe-mjx plot`
and the curve figures); `tb/` is the same data for TensorBoard on the machine that trained, and
is never committed. Columns: `env_steps`, `wall_time` (seconds since the epoch), then one column
per tag in sorted order; a cell is empty where the tag was not logged at that point (the
evaluation's tags, every `eval_every` iterations). Readable as it is with
`pandas.read_csv("curves.csv.xz")`.

Compressed because a 10M-step run logs about 4,900 points of about 80 tags (1.8 MB of CSV).
Precision, a decision: the training diagnostics (`loss/`, `reward/`, `perf/`, `ppo/`:
per-iteration noise read as curves) keep 4 significant digits, the episode and evaluation tags
(`episode/`, `eval/`, which tables and model cards quote) keep 6. Format, a decision (2026-12-06):
xz (LZMA, Python's `lzma`, preset 6) rather than gzip, as the committed runs' curves are most of
the repository's size: a 10M-step run's file is 0.45 MB instead of 0.58 MB, 19% less over every
committed run. The price is paid at each checkpoint (every 20 iterations), where the file is
rewritten whole: for a 10M-step run's 4,883 rows, 1.3 s instead of 0.5 s (2-core CPU beside a
training run, 2026-12-06), under 1% of the 90 s between two checkpoints there. Runs written
before that keep a `curves.csv.gz` (`LEGACY_FILE`): it is read the same way (`curves_file`),
and a resumed run rewrites it as `curves.csv.xz`.

The file is rewritten whole (a temporary beside it, then one rename) just before
each checkpoint is saved, so it never holds fewer points than the checkpoint it belongs to; on
resume the points beyond the restored checkpoint (logged after it, before a kill) are dropped,
so they are logged once, as the resumed run replays them.
"""

from __future__ import annotations

import contextlib
import csv
import gzip
import io
import itertools
import lzma
import math
import os
import statistics
import time
from pathlib import Path
from typing import Any

CURVES_FILE = "curves.csv.xz"
LEGACY_FILE = "curves.csv.gz"
"""The gzip curves of runs written before 2026-12-06 (read, never written)."""
MAX_BYTES = 64 << 20
"""Largest decompressed curves file read (a 10M-step run's is about 2 MB)."""
MAX_COLUMNS = 10_000
PRESET = 6
"""xz preset: 9 gives the same size on curves, 0-3 up to 35% more."""
DIAGNOSTIC_PREFIXES = ("loss/", "reward/", "perf/", "ppo/")
"""Tags kept at 4 significant digits (the rest at 6)."""
PAUSE_S = 600
"""An interval between two rows longer than this (seconds) is a pause between resumed chunks
(`training_time`)."""


class CurvesError(ValueError):
    """A curves file that cannot be read (damaged, too large, or not a curves file)."""


def curves_file(run_dir: str | Path) -> Path:
    """The curves of a run directory: its `curves.csv.xz`, else the `curves.csv.gz` of a run
    written before that format (where neither exists, the path of the first)."""
    path = Path(run_dir) / CURVES_FILE
    legacy = Path(run_dir) / LEGACY_FILE
    return legacy if not path.exists() and legacy.exists() else path


def read_rows(path: str | Path) -> list[dict[str, float]]:
    """The rows of a curves file, each `{"env_steps": ..., "wall_time": ..., tag: value}` with
    the empty cells left out.

    Raises:
      CurvesError: the file is not an xz (or a legacy gzip) CSV with an `env_steps` column,
        holds a value that is not a number, or decompresses to more than `MAX_BYTES` (checked
        while reading).
    """
    path = Path(path)
    gzipped = False
    try:
        if not path.is_file():
            raise CurvesError(f"{path} is not a regular file")
        with open(path, "rb") as raw:
            gzipped = raw.read(2) == b"\x1f\x8b"  # by its bytes, not its name
            raw.seek(0)
            with gzip.GzipFile(fileobj=raw) if gzipped else lzma.LZMAFile(raw) as f:
                data = f.read(MAX_BYTES + 1)
    except (OSError, EOFError, lzma.LZMAError) as err:  # gzip.BadGzipFile is an OSError
        kind = "gzip" if gzipped else "xz"
        raise CurvesError(f"{path}: not a readable {kind} file ({err})") from None
    if len(data) > MAX_BYTES:
        raise CurvesError(f"{path}: larger than {MAX_BYTES >> 20} MB decompressed")
    try:
        reader = csv.reader(io.StringIO(data.decode()))
        header = next(reader, None)
    except (UnicodeDecodeError, csv.Error) as err:
        raise CurvesError(f"{path}: not a CSV file ({err})") from None
    if not header or header[0] != "env_steps" or len(header) > MAX_COLUMNS:
        raise CurvesError(f"{path}: not a curves file (its first column must be env_steps)")
    rows = []
    try:
        for line, cells in enumerate(reader, start=2):
            if len(cells) != len(header):
                raise CurvesError(f"{path}: line {line} has {len(cells)} cells, not {len(header)}")
            row = {k: float(v) for k, v in zip(header, cells, strict=True) if v != ""}
            # The writer leaves a non-finite value's cell empty (`_cell`): nan, inf or a
            # fractional or negative step count is a damaged file (1e400 steps was a traceback).
            bad = next((k for k, v in row.items() if not math.isfinite(v)), None)
            if bad is not None:
                raise CurvesError(f"{path}: line {line}: {bad} is {row[bad]}, not a finite number")
            steps = row["env_steps"]
            if not 0 <= steps < 2**63 or steps != int(steps):  # an int64 counter
                raise CurvesError(f"{path}: line {line}: env_steps is {steps:g}, not a step count")
            row["env_steps"] = int(steps)
            rows.append(row)
    except (ValueError, KeyError, csv.Error) as err:
        if isinstance(err, CurvesError):
            raise
        raise CurvesError(f"{path}: line {line} is not a row of numbers") from None
    return rows


def scalars(rows: list[dict[str, float]]) -> dict[str, list[tuple[int, float]]]:
    """tag -> [(env_steps, value)], sorted by env steps (the shape of TensorBoard's scalars)."""
    out: dict[str, list[tuple[int, float]]] = {}
    for row in rows:
        step = int(row["env_steps"])
        for tag, value in row.items():
            if tag not in ("env_steps", "wall_time"):
                out.setdefault(tag, []).append((step, value))
    return {tag: sorted(points) for tag, points in out.items()}


def training_time(rows: list[dict[str, float]], pause_s: float = PAUSE_S) -> dict[str, Any]:
    """Hours of training that a run's rows record, by their wall clock (`wall_time`).

    A run resumed several times has pauses between its chunks, so its time is the sum of the
    intervals between consecutive rows, where an interval longer than `pause_s` (10 minutes: an
    evaluation or a restart inside a chunk takes a few minutes at most; the result gives the
    longest interval counted and the shortest pause) is a pause and counts as one median
    interval of the run (the iteration that ended it). The start-up before the first row is not
    logged and not counted."""
    times = [r["wall_time"] for r in rows]
    intervals = [b - a for a, b in itertools.pairwise(times)]
    median = statistics.median(intervals)
    pauses = [i for i in intervals if i > pause_s]
    counted = [i for i in intervals if i <= pause_s]
    return {
        "env_steps": int(rows[-1]["env_steps"]),
        "rows": len(rows),
        "median_interval_s": round(median, 1),
        "longest_counted_s": round(max(counted), 1),
        "pauses": len(pauses),
        "shortest_pause_s": round(min(pauses), 1) if pauses else None,
        "paused_h": round(sum(pauses) / 3600, 2),
        "hours": round((sum(counted) + median * len(pauses)) / 3600, 2),
    }


def write_rows(path: str | Path, rows: list[dict[str, float]]) -> None:
    """Writes `rows` as a curves file: a temporary beside `path`, then one rename."""
    path = Path(path)
    tags = sorted({k for row in rows for k in row} - {"env_steps", "wall_time"})
    header = ["env_steps", "wall_time", *tags]
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([_cell(row.get(k), k) for k in header])
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        # xz holds no time stamp: the same rows give the same bytes (no spurious diff).
        tmp.write_bytes(lzma.compress(text.getvalue().encode(), preset=PRESET))
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def _cell(value: float | None, key: str) -> str:
    if value is None or not math.isfinite(value):
        return ""
    if key == "env_steps":
        return str(int(value))
    if key == "wall_time":
        return f"{value:.1f}"
    return f"{value:.4g}" if key.startswith(DIAGNOSTIC_PREFIXES) else f"{value:.6g}"


class CurveLog:
    """The curves of one run while it trains: `add` a log point, `flush` to disk.

    Args:
      run_dir: the run directory.
      resume_at: on resume, the env steps of the restored checkpoint: the existing file's points
        up to it are kept (a damaged or absent file starts empty). None: a fresh run, whose file
        starts empty.
    """

    def __init__(self, run_dir: str | Path, resume_at: int | None) -> None:
        self.path = Path(run_dir) / CURVES_FILE
        self.rows: list[dict[str, float]] = []
        found = curves_file(run_dir)  # a legacy curves.csv.gz is read, then rewritten as xz
        if resume_at is not None and found.is_file():
            try:
                self.rows = [r for r in read_rows(found) if r["env_steps"] <= resume_at]
            except CurvesError:
                self.rows = []
        self._dirty = True

    def add(self, env_steps: int, values: dict[str, float]) -> None:
        row = {k: float(v) for k, v in values.items() if math.isfinite(v)}
        row.update(env_steps=int(env_steps), wall_time=time.time())
        self.rows.append(row)
        self._dirty = True

    def flush(self) -> None:
        if self._dirty:
            write_rows(self.path, self.rows)
            self._dirty = False
            with contextlib.suppress(FileNotFoundError):  # one curves file per run
                (self.path.parent / LEGACY_FILE).unlink()


__all__ = [
    "CURVES_FILE",
    "LEGACY_FILE",
    "CurveLog",
    "CurvesError",
    "curves_file",
    "read_rows",
    "scalars",
    "write_rows",
]
