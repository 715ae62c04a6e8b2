"""Runs chosen tests many times in a row and records every outcome: flaky tests are bugs.

    python tools/stress_tests.py TEST_ID [TEST_ID ...] [--runs 20] [--load 1] [--out FILE]

Each run is a fresh `pytest` process (as CI runs it). `--load N` keeps N busy-looping processes
beside the runs, so that the tests meet a machine as loaded as CI's (2 cores, the rest of the
suite, a training run). The JSON file holds, per run, the exit code, the wall time and the load
average, and the summary the docs quote.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path

import tyro


@dataclasses.dataclass(frozen=True)
class Args:
    tests: tyro.conf.Positional[tuple[str, ...]]
    """pytest node ids, e.g. tests/test_cli.py::test_train_interrupted_keeps_its_checkpoint..."""
    runs: int = 20
    load: int = 1
    """Busy-looping processes kept running beside the tests."""
    out: Path = Path("docs/stress_tests.json")
    timeout: float = 900.0
    """Seconds before one pytest run counts as hung (and is killed)."""


def _spin() -> None:
    while True:
        pass


def main() -> None:
    args = tyro.cli(Args)
    burners = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(args.load)]
    for p in burners:
        p.start()
    results = []
    try:
        for i in range(args.runs):
            tic = time.monotonic()
            cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args.tests]
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
                code, tail = proc.returncode, proc.stdout[-12000:]
            except subprocess.TimeoutExpired:
                code, tail = "timeout", ""
            row = {
                "run": i,
                "exit": code,
                "seconds": round(time.monotonic() - tic, 1),
                "load_avg_1min": os.getloadavg()[0],
            }
            print(json.dumps(row), flush=True)
            if code != 0:
                row["tail"] = tail
            results.append(row)
    finally:
        for p in burners:
            p.terminate()
    failures = sum(r["exit"] != 0 for r in results)
    summary = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"),
        "cores": os.cpu_count(),
        "tests": list(args.tests),
        "runs": args.runs,
        "load_processes": args.load,
        "failures": failures,
        "max_seconds": max(r["seconds"] for r in results),
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=1))
    print(f"{failures} of {args.runs} runs failed; the longest took {summary['max_seconds']} s")
    raise SystemExit(1 if failures else 0)


if __name__ == "__main__":
    main()
