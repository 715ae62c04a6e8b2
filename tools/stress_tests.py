"""Runs chosen tests many times in a row and records every outcome: flaky tests are bugs.

    python tools/stress_tests.py TEST_ID [TEST_ID ...] [--runs 20] [--load 1] [--out FILE]

Each run is a fresh `pytest` process (as CI runs it). `--load N` keeps N busy-looping processes
beside the runs, so that the tests meet a machine as loaded as CI's (2 cores, the rest of the
suite, a training run). The JSON file holds, per run, the exit code, the wall time and the load
average, and the summary the docs quote.

    python tools/stress_tests.py browser [--runs 20] [--load 1] [--beside "PYTEST ARGS"]

runs the viewer's browser test that once missed the new scene's name under the suite's load,
with a pytest of heavy test files beside it as the suite's other worker (`BrowserArgs`), and
writes docs/stress_browser.json. `interrupts` sends Ctrl-C into pe-mjx commands
(`InterruptArgs`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import json
import multiprocessing
import os
import shlex
import subprocess
import sys
import threading
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
    if sys.argv[1:2] == ["interrupts"]:  # Ctrl-C at random times into pe-mjx commands
        interrupts_main(sys.argv[2:])
        return
    if sys.argv[1:2] == ["browser"]:  # the viewer's browser test beside a suite-like load
        browser_main(sys.argv[2:])
        return
    args = tyro.cli(Args)
    burners = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(args.load)]
    for p in burners:
        p.start()
    results = []
    try:
        for i in range(args.runs):
            cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args.tests]
            row, tail = _timed_run(i, cmd, args.timeout)
            code = row["exit"]
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


# ------------------------------------------------------------------ interrupts


@dataclasses.dataclass(frozen=True)
class InterruptArgs:
    """python tools/stress_tests.py interrupts [--runs 20] [--load 1] [--commands evaluate train]

    Starts each command `--runs` times, sends it one SIGINT at a random time (uniform over the
    length of an uninterrupted run, measured first, or `--max-delay` for a command that runs
    until stopped) and classifies the outcome: clean (exit 130, one line "pe-mjx: interrupted",
    no traceback), crashed (another exit code, a signal death, a hang, a traceback, "Fatal Python
    error" or "Exception ignored" on stderr), lost (exit 0: the interrupt was swallowed and the
    command ran to its end) or late (the command had ended before the signal: not counted). An
    evaluation's --out must be absent or whole afterwards (partial: counted as crashed)."""

    commands: tuple[str, ...] = ("evaluate", "train")
    """evaluate, train, or train-loop (train, the signal 0-10 s after its first checkpoint)."""
    runs: int = 20
    load: int = 1
    """Busy-looping processes kept running beside the commands."""
    max_delay: float = 60.0
    """The latest SIGINT into a command that does not end by itself (train)."""
    timeout: float = 120.0
    """Seconds after the SIGINT before a command counts as hung (and is killed)."""
    seed: int = 0
    out: Path = Path("docs/stress_tests_interrupts.json")
    workdir: Path = Path("/tmp/pe-mjx-stress-interrupts")


EVALUATE = (
    "evaluate --pursuers scripted --evaders scripted --preset 4-1-2 --backend kinematic "
    "--trials 8 --record 1 --no-progress --out {out}"
)
TRAIN = (
    "train --preset 2-1-1 --backend kinematic --evader.policy scripted --env-steps 100000000 "
    "--ppo.num-envs 2 --ppo.unroll-length 4 --ppo.num-minibatches 1 --ppo.update-epochs 1 "
    "--pursuer.network.width 8 --pursuer.network.num-heads 2 --pursuer.network.hidden 16 "
    "--eval-every 0 --checkpoint-every 20 --no-progress --out {out}"
)


def _timed_run(
    run: int, cmd: list[str], timeout: float, env: dict | None = None
) -> tuple[dict, str]:
    """Runs `cmd` once: its row (run, exit code or "timeout", seconds, load) and stdout's tail."""
    tic = time.monotonic()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
        code, tail = proc.returncode, proc.stdout[-12000:]
    except subprocess.TimeoutExpired:
        code, tail = "timeout", ""
    row = {
        "run": run,
        "exit": code,
        "seconds": round(time.monotonic() - tic, 1),
        "load_avg_1min": round(os.getloadavg()[0], 2),
    }
    return row, tail


def classify(code: int | str, stderr: str) -> str:
    """clean, crashed or lost (see `InterruptArgs`)."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    stops = [line for line in lines if line.startswith("pe-mjx: interrupted")]
    bad = ("Traceback", "Fatal Python error", "Exception ignored", "Segmentation fault")
    if code == 0 or (code == "hung" and not stops):  # ran to its end, or went on running
        return "lost"
    if code != 130 or any(b in stderr for b in bad) or len(stops) != 1 or lines[-1] != stops[0]:
        return "crashed"
    return "clean"


def _machine() -> dict:
    import platform

    memory = None
    with contextlib.suppress(OSError, ValueError, IndexError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                memory = f"{int(line.split()[1]) / 1e6:.1f} GB"
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "memory": memory,
        "python": platform.python_version(),
    }


def _cli() -> list[str]:
    script = Path(sys.executable).parent / "pe-mjx"
    return [str(script)] if script.exists() else [sys.executable, "-m", "pe_mjx.cli"]


def _one(
    command: str, out: Path, delay: float | None, timeout: float, log: Path, loop: bool = False
) -> dict:
    """One run of `command`, SIGINT after `delay` s (None: none), counted from its first
    checkpoint with `loop` (train: the signal lands in the training loop); its outcome."""
    import shlex
    import shutil
    import signal

    shutil.rmtree(out, ignore_errors=True)
    cmd = [*_cli(), *shlex.split(command.format(out=out))]
    tic = time.monotonic()
    with open(log, "w") as err:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True, cwd=out.parent
        )
        row: dict = {"delay": None if delay is None else round(delay, 2)}
        try:
            while loop and not any(out.glob("checkpoints/*/commit_success.txt")):
                if proc.poll() is not None or time.monotonic() - tic > 900:
                    break
                time.sleep(0.2)
            if loop:
                row["first_checkpoint_s"] = round(time.monotonic() - tic, 1)
            if delay is not None:
                try:
                    proc.wait(timeout=delay)
                    row["outcome"] = "late"  # it ended before the signal
                except subprocess.TimeoutExpired:
                    proc.send_signal(signal.SIGINT)
                    sent = time.monotonic()
            if "outcome" not in row:
                try:
                    code = proc.wait(timeout=timeout if delay is not None else 3600)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                    code = "hung"
                row["exit"] = code
                if delay is not None:
                    row["seconds_to_exit"] = round(time.monotonic() - sent, 2)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    row["seconds"] = round(time.monotonic() - tic, 1)
    row["load_avg_1min"] = round(os.getloadavg()[0], 2)
    stderr = log.read_text(errors="replace")
    if delay is not None and row.get("outcome") != "late":
        row["outcome"] = classify(row["exit"], stderr)
        if command.startswith("evaluate") and out.exists():
            whole = all((out / name).is_file() for name in ("results.json", "results.md"))
            if not whole:
                row["outcome"] = "crashed"
                row["partial_out"] = sorted(p.name for p in out.iterdir())
        if row["outcome"] != "clean":
            row["stderr_tail"] = stderr[-3000:]
    return row


def interrupts_main(argv: list[str]) -> None:
    import random

    args = tyro.cli(InterruptArgs, args=argv, prog="stress_tests.py interrupts")
    rng = random.Random(args.seed)
    args.workdir.mkdir(parents=True, exist_ok=True)
    burners = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(args.load)]
    for p in burners:
        p.start()
    report: dict = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"),
        "machine": _machine(),
        "load_processes": args.load,
        "runs": args.runs,
        "seed": args.seed,
        "commands": {},
    }
    try:
        for name in args.commands:
            command = {"evaluate": EVALUATE, "train": TRAIN, "train-loop": TRAIN}[name]
            loop = name == "train-loop"  # the delay counts from the first checkpoint
            out = args.workdir / f"{name}-out"
            log = args.workdir / f"{name}-stderr.txt"
            if name == "evaluate":  # the signals fall anywhere in an uninterrupted run's length
                full = _one(command, out, None, args.timeout, log)
                span = full["seconds"]
                print(json.dumps({"calibration": name, **full}), flush=True)
            else:
                span = 10.0 if loop else args.max_delay
            rows = []
            for i in range(args.runs):
                delay = rng.uniform(0.0 if loop else 0.5, span)
                row = {"run": i, **_one(command, out, delay, args.timeout, log, loop)}
                print(json.dumps({"command": name, **row}), flush=True)
                rows.append(row)
            counted = [r for r in rows if r["outcome"] != "late"]
            report["commands"][name] = {
                "command": "pe-mjx " + command.format(out="OUT"),
                "delay_range_s": [0.0 if loop else 0.5, round(span, 1)],
                "delay_from": "the first checkpoint" if loop else "the start",
                "interrupted": len(counted),
                "clean": sum(r["outcome"] == "clean" for r in counted),
                "crashed": sum(r["outcome"] == "crashed" for r in counted),
                "lost": sum(r["outcome"] == "lost" for r in counted),
                "late": len(rows) - len(counted),
                "max_seconds_to_exit": max((r["seconds_to_exit"] for r in counted), default=None),
                "results": rows,
            }
    finally:
        for p in burners:
            p.terminate()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1) + "\n")
    bad = 0
    for name, r in report["commands"].items():
        bad += r["crashed"] + r["lost"]
        print(
            f"{name}: {r['interrupted']} interrupted, {r['crashed']} crashed, {r['lost']} lost, "
            f"{r['late']} late; slowest exit {r['max_seconds_to_exit']} s after the signal"
        )
    raise SystemExit(1 if bad else 0)


# ------------------------------------------------------------------ browser


BROWSER_TEST = "tests/viewer/test_viewer_browser.py::test_scene_controls_reset_and_apply"
SUITE_ENV = {
    # As `make test` runs the suite: the persistent compile cache, every entry kept.
    "JAX_COMPILATION_CACHE_DIR": str(Path(".cache/jax").resolve()),
    "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
    "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "-1",
}


@dataclasses.dataclass(frozen=True)
class BrowserArgs:
    """python tools/stress_tests.py browser [--runs 20] [--load 1] [--beside FILE ...]

    Runs the viewer's browser test (`--test`) `--runs` times, each a fresh pytest process with
    `make test`'s environment, while the load of the suite's other worker runs beside it: a
    pytest process on `--beside` (CPU-heavy test files, restarted whenever it ends), plus
    `--load` busy-looping processes. `make test` runs two workers on two cores, so one heavy
    pytest beside the browser test is the suite's load; the busy processes stand for the
    training run a developer machine often has too. The test is run through pytest, never
    imported: a tool does not import tests. Writes the counts, the machine and the date, and per
    run and per beside run the exit code, the wall time and the load average."""

    test: str = BROWSER_TEST
    runs: int = 20
    load: int = 1
    """Busy-looping processes kept running beside the tests."""
    beside: str = "tests/ppo/test_train.py tests/test_rules.py"
    """pytest arguments of the load run beside, as one shell-quoted string (empty: none)."""
    timeout: float = 900.0
    """Seconds before one run of the test counts as hung (and is killed)."""
    out: Path = Path("docs/stress_browser.json")


def _pytest(args: tuple[str, ...] | list[str]) -> list[str]:
    return [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args]


class _Beside:
    """The pytest load beside the runs: one process at a time, restarted when it ends."""

    def __init__(self, args: tuple[str, ...], env: dict[str, str]):
        self.args, self.env, self.runs = args, env, []
        self._stop = threading.Event()
        self._proc: subprocess.Popen | None = None
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        while not self._stop.is_set():
            tic = time.monotonic()
            self._proc = subprocess.Popen(
                _pytest(["-s", *self.args]),
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                env=self.env,
            )
            output = self._proc.communicate()[0]
            if self._stop.is_set():
                break  # stopped from outside: not a run of its own
            lines = [line for line in output.splitlines() if line.strip()]
            self.runs.append(
                {
                    "exit": self._proc.returncode,
                    "seconds": round(time.monotonic() - tic, 1),
                    "summary": lines[-1] if lines else "",
                    "tail": lines[-25:],
                }
            )
            print(json.dumps({"beside": self.runs[-1]}), flush=True)

    def start(self) -> None:
        if self.args:
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._proc is not None and self._proc.poll() is None:
            self._proc.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(timeout=30)
        if self._thread.is_alive():
            self._thread.join(timeout=60)


def browser_main(argv: list[str]) -> None:
    args = tyro.cli(BrowserArgs, args=argv, prog="stress_tests.py browser")
    env = {**os.environ, **SUITE_ENV}
    burners = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(args.load)]
    for p in burners:
        p.start()
    beside = _Beside(tuple(shlex.split(args.beside)), env)
    beside.start()
    started = datetime.datetime.now(datetime.UTC)
    results = []
    try:
        for i in range(args.runs):
            row, tail = _timed_run(i, _pytest([args.test]), args.timeout, env)
            code = row["exit"]
            print(json.dumps(row), flush=True)
            if code != 0:
                row["tail"] = tail
            results.append(row)
    finally:
        beside.stop()
        for p in burners:
            p.terminate()
    failures = sum(r["exit"] != 0 for r in results)
    seconds = sorted(r["seconds"] for r in results)
    summary = {
        "date": started.isoformat(timespec="minutes"),
        "finished": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"),
        "machine": _machine(),
        "test": args.test,
        "runs": args.runs,
        "failures": failures,
        "passed": args.runs - failures,
        "load_processes": args.load,
        "beside": args.beside,
        "beside_runs": len(beside.runs),
        "median_seconds": seconds[len(seconds) // 2] if seconds else None,
        "max_seconds": seconds[-1] if seconds else None,
        "max_load_avg_1min": max((r["load_avg_1min"] for r in results), default=None),
        "results": results,
        "beside_results": beside.runs,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=1) + "\n")
    print(
        f"{failures} of {args.runs} runs failed; median {summary['median_seconds']} s, longest "
        f"{summary['max_seconds']} s; {len(beside.runs)} beside runs"
    )
    raise SystemExit(1 if failures else 0)


if __name__ == "__main__":
    main()
