"""Training throughput on one process and on a group of processes (jax.distributed), in one run.

    python tools/bench_distributed.py [--preset 20-5-8] [--iterations 12]

Runs the same `pe-mjx train` (MIX co-evolution, evaluation off) for `--iterations` iterations in
each layout, one after the other on this machine:
  * 1 process, 1 CPU device (the default);
  * 1 process, 2 CPU devices (`--xla_force_host_platform_device_count=2`: the env batch split in
    two within the process);
  * 2 processes of 1 device each on localhost (`--coordinator-address`, gloo collectives).
Throughput is the median of the run's own `perf/env_steps_per_s` over its iterations after the
first (which compiles). On one machine the processes share its cores, so the group measures the
cost of the collectives and of the split, not a speed-up; across machines each brings its cores.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import tyro

from pe_mjx.plots import read_scalars


@dataclasses.dataclass(frozen=True)
class Args:
    preset: str = "20-5-8"
    iterations: int = 12
    """Iterations per layout (the first compiles and is not counted)."""
    num_envs: int = 64
    out: Path = Path("docs/bench_distributed.json")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(args: Args, run_dir: Path, devices: int, processes: int) -> float:
    flags = [
        *("--preset", args.preset, "--backend", "kinematic", "--no-progress"),
        *("--pursuer.network.encoder", "mix", "--evader.network.encoder", "mix"),
        *("--ppo.num-envs", str(args.num_envs), "--eval-every", "0"),
        *("--stop-after", str(args.iterations), "--checkpoint-every", "1000"),
        *("--out", str(run_dir)),
    ]
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}
    group = []
    if processes > 1:
        group = ["--coordinator-address", f"127.0.0.1:{_port()}"]
        group += ["--num-processes", str(processes)]
    cmd = [sys.executable, "-m", "pe_mjx.cli", "train", *flags, *group]
    procs = [
        subprocess.Popen(
            cmd + (["--process-id", str(i)] if processes > 1 else []),
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(processes)
    ]
    for p in procs:
        _, err = p.communicate(timeout=3600)
        if p.returncode:
            raise SystemExit(f"bench_distributed: {' '.join(cmd)} failed: {err[-2000:]}")
    speeds = [v for _, v in read_scalars(run_dir)["perf/env_steps_per_s"]][1:]
    return statistics.median(speeds)


def main(args: Args) -> None:
    layouts = [("1 process x 1 device", 1, 1), ("1 process x 2 devices", 2, 1)]
    layouts.append(("2 processes x 1 device", 1, 2))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, devices, processes) in enumerate(layouts):
            speed = _run(args, Path(tmp) / f"run{i}", devices, processes)
            rows.append({"layout": name, "devices": devices * processes, "env_steps_per_s": speed})
            print(f"{name}: {speed:,.0f} env-steps/s", flush=True)
    base = rows[0]["env_steps_per_s"]
    for row in rows:
        row["ratio_to_one_device"] = row["env_steps_per_s"] / base
    result = {
        "date": datetime.date.today().isoformat(),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "preset": args.preset,
        "encoder": "mix",
        "num_envs": args.num_envs,
        "iterations": args.iterations,
        "rows": rows,
    }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print("| layout | devices | env-steps/s | vs 1 device |\n|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['layout']} | {row['devices']} | {row['env_steps_per_s']:,.0f} | "
            f"{row['ratio_to_one_device']:.2f}x |"
        )


if __name__ == "__main__":
    main(tyro.cli(Args))
