"""Env-step throughput: pe-mjx's `env.step` (both backends) against JaxMARL's MPE simple tag.

    .venv/bin/python tools/bench_env.py [--quick] [--out docs/bench_env.json]
        [--markdown docs/benchmarks.md]

What is timed (tools/bench_env_worker.py, which this script starts once per configuration, says how
in detail): the full `env.step`, `jit` of `vmap` over a batch of arenas, `--steps` steps per call
under `jax.lax.scan`, beside JaxMARL's `MPE_simple_tag_v3` with the same counts; and in the
breakdown (batch 256 at 20-5-8 unless changed) each part of a step on its own. JaxMARL is the
`bench` extra (`pip install -e ".[bench]"`); without it those rows are recorded as skipped.

Each (implementation, preset, batch) runs in its own subprocess, so that its peak resident set size
(`resource.getrusage(RUSAGE_SELF).ru_maxrss`, which includes the ~0.5 GB of Python, JAX and XLA
loaded before anything is built; reported separately as `baseline_rss_mb`) belongs to it alone.
Configurations predicted, from the smaller batches of the same implementation, to need more than
`--max-seconds-total` are skipped and recorded with the reason. Memory is never predicted into a
skip: every configuration runs, and the parent polls its worker's resident memory and stops it
(recorded with the measured size) once it exceeds `--max-memory-gb`, or once it runs past the hard
`--timeout`. Throughput is the best of the timed calls (the machine is shared and noisy: the best
call is the least disturbed one); the median is in the JSON too. Implementations run interleaved per
batch size, so the ours/JaxMARL ratios come from the same minutes of the same run.

`--quick` is a smoke run (small batches, few calls) that writes `results/bench_env_quick.json` and
no Markdown unless told otherwise.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import importlib.util
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
WORKER = Path(__file__).resolve().parent / "bench_env_worker.py"
PRESETS = ("20-5-8", "240-60-120")
BATCHES = (1, 16, 256, 4096)
IMPLS = ("jaxmarl", "kinematic", "mjx")
SECTION = "## Env step throughput"
RESULT_TAG = "BENCH_RESULT "  # a worker's result line (tools/bench_env_worker.py)


def machine_info() -> dict[str, Any]:
    import jax
    import jaxlib
    import mujoco

    cpu = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu_model": cpu,
        "cpu_cores": os.cpu_count(),
        "memory_gb": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "jax_backend": jax.default_backend(),
        "mujoco": mujoco.__version__,
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "load_average_at_start": list(os.getloadavg()),
        "jaxmarl": _jaxmarl_version(),
    }


def _jaxmarl_version() -> str | None:
    """JaxMARL's installed version, or None (without importing it: that is slow and noisy)."""
    if importlib.util.find_spec("jaxmarl") is None:
        return None
    return importlib.metadata.version("jaxmarl")


def _rss_of(pid: int) -> float:
    """Resident set size of a live process in MB (Linux /proc), 0 if it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def run_worker(spec: dict[str, Any], timeout: float, max_memory_gb: float) -> dict[str, Any]:
    """Runs one configuration in a subprocess, stopping it past `timeout` seconds or once its
    measured resident memory exceeds `max_memory_gb` (polled every 0.1 s)."""
    cmd = [sys.executable, str(WORKER), json.dumps(spec)]
    env = dict(os.environ)
    env.setdefault("PYTHONPATH", str(ROOT))
    limit_mb = max_memory_gb * 1024
    peak = 0.0
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, cwd=ROOT, env=env)
        start = time.monotonic()
        reason = None
        while proc.poll() is None:
            peak = max(peak, _rss_of(proc.pid))
            if peak > limit_mb:
                reason = (
                    f"stopped at a measured {peak / 1024:.1f} GB resident > --max-memory-gb "
                    f"{max_memory_gb:g}"
                )
            elif time.monotonic() - start > timeout:
                reason = f"ran past the {timeout:.0f} s timeout"
            if reason:
                proc.kill()
                proc.wait()
                return {"status": "skipped", "reason": reason}
            time.sleep(0.1)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    for line in stdout.splitlines():
        if line.startswith(RESULT_TAG):
            return json.loads(line[len(RESULT_TAG) :])
    tail = (stderr or stdout).strip().splitlines()[-3:]
    if proc.returncode < 0 or proc.returncode == 137:
        reason = f"worker killed (signal {-proc.returncode}), probably out of memory"
    else:
        reason = f"worker failed (exit {proc.returncode}): {' | '.join(tail)}"
    return {"status": "skipped", "reason": reason}


def predict(
    history: list[dict[str, Any]], batch: int, args: argparse.Namespace
) -> dict[str, float]:
    """Steps per call, peak memory (MB) and wall time (s) of `batch`, from smaller batches.

    Time per env-step does not grow with the batch (it usually shrinks), so scaling the last
    measurement linearly is an upper bound. Memory grows linearly beyond the baseline: with two
    measurements their slope is used, with one everything above the baseline is assumed to scale
    (an overestimate, hence safe). Calls longer than `--max-call-seconds` get fewer steps.
    """
    ok = [r for r in history if r.get("status") == "ok"]
    if not ok:
        return {}
    last = ok[-1]
    if len(ok) >= 2:
        prev = ok[-2]
        slope = max(last["peak_rss_mb"] - prev["peak_rss_mb"], 0.0) / (
            last["batch"] - prev["batch"]
        )
    else:
        slope = (last["peak_rss_mb"] - last["baseline_rss_mb"]) / last["batch"]
    memory = last["peak_rss_mb"] + slope * (batch - last["batch"])
    per_env_step = last["seconds_per_call_best"] / (last["batch"] * last["steps_per_call"])
    steps = args.steps
    if per_env_step * batch * steps > args.max_call_seconds:
        steps = max(args.min_steps, int(args.max_call_seconds / (per_env_step * batch)))
    per_call = per_env_step * batch * steps
    timed = max(2 * per_call, min(args.min_calls * per_call, args.max_seconds))
    seconds = last["compile_s"] + per_call + timed  # compile, warm-up call, timed calls
    return {"steps": steps, "memory_mb": memory, "seconds": seconds, "seconds_per_call": per_call}


def collect(args: argparse.Namespace) -> dict[str, Any]:
    have_jaxmarl = _jaxmarl_version() is not None
    results: list[dict[str, Any]] = []
    history: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for preset in args.presets:
        for batch in args.batches:
            for impl in args.impls:
                if impl == "jaxmarl" and preset not in args.jaxmarl_presets:
                    continue
                hist = history.setdefault((impl, preset), [])
                guess = predict(hist, batch, args)
                spec = {
                    "impl": impl,
                    "preset": preset,
                    "batch": batch,
                    "steps": int(guess.get("steps", args.steps)),
                    "actions": args.actions,
                    "min_calls": args.min_calls,
                    "min_seconds": args.min_seconds,
                    "max_seconds": args.max_seconds,
                }
                reason = None
                if impl == "jaxmarl" and not have_jaxmarl:
                    reason = "jaxmarl is not installed (pip install -e '.[bench]')"
                elif any(r.get("status") != "ok" for r in hist):
                    reason = "a smaller batch of this implementation was skipped"
                elif guess and guess["seconds"] > args.max_seconds_total:
                    reason = (
                        f"predicted {guess['seconds']:.0f} s (compile, then calls of "
                        f"{guess['seconds_per_call']:.1f} s for {spec['steps']} steps) > "
                        f"{args.max_seconds_total:g} s"
                    )
                if reason is None:
                    print(f"[bench_env] {impl:9s} {preset:10s} batch {batch:5d} ...", flush=True)
                    row = run_worker(spec, args.timeout, args.max_memory_gb)
                else:
                    row = {"status": "skipped", "reason": reason}
                row = {"impl": impl, "preset": preset, "batch": batch, **row}
                if guess:
                    row["predicted"] = {k: round(v, 2) for k, v in guess.items()}
                hist.append(row)
                results.append(row)
                if row["status"] == "ok":
                    print(
                        f"[bench_env] {impl:9s} {preset:10s} batch {batch:5d}: "
                        f"{row['env_steps_per_s']:12,.0f} env-steps/s, "
                        f"compile {row['compile_s']:.1f} s, peak {row['peak_rss_mb']:.0f} MB",
                        flush=True,
                    )
                else:
                    print(
                        f"[bench_env] {impl:9s} {preset:10s} batch {batch:5d}: skipped, "
                        f"{row['reason']}",
                        flush=True,
                    )
    return {"results": results, "ratios": ratios(results)}


def ratios(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    ok = {(r["impl"], r["preset"], r["batch"]): r for r in results if r["status"] == "ok"}
    out = []
    for (impl, preset, batch), row in sorted(ok.items()):
        anchor = ok.get(("jaxmarl", preset, batch))
        if impl == "jaxmarl" or anchor is None:
            continue
        out.append(
            {
                "backend": impl,
                "preset": preset,
                "batch": batch,
                "ours_env_steps_per_s": row["env_steps_per_s"],
                "jaxmarl_env_steps_per_s": anchor["env_steps_per_s"],
                "ratio_ours_over_jaxmarl": row["env_steps_per_s"] / anchor["env_steps_per_s"],
                "ratio_median": row["env_steps_per_s_median"] / anchor["env_steps_per_s_median"],
            }
        )
    return out


# ----------------------------------------------------------------------------- markdown


def _fmt(x: float) -> str:
    return f"{x:,.0f}"


def markdown(report: dict[str, Any]) -> str:
    m = report["machine"]
    s = report["settings"]
    lines = [
        SECTION,
        "",
        f"Generated by `tools/bench_env.py` on {m['date']}: {m['cpu_model']}, {m['cpu_cores']} "
        f"cores, {m['memory_gb']} GB, jax {m['jax']} ({m['jax_backend']}), mujoco {m['mujoco']}, "
        f"JaxMARL {m.get('jaxmarl') or 'not installed'}. Load average at start: "
        f"{', '.join(f'{x:.1f}' for x in m['load_average_at_start'])} (the machine is shared).",
        "",
        "Full `env.step` (observations, action masks, rewards, metrics), `jit(vmap)` over the "
        "batch, stepped under `lax.scan` (steps per call in the table), "
        f"{s['actions']} valid actions; env-steps/s is the best timed call (median in the JSON). "
        "JaxMARL is `MPE_simple_tag_v3` with the same counts (adversaries = pursuers, good "
        "agents = evaders, landmarks = obstacles), random actions, its step (with auto-reset) "
        f"under the same scan, measured in the same run at {', '.join(s['jaxmarl_presets'])}; "
        "the ratio is ours / JaxMARL. Peak memory is the worker process's `ru_maxrss` "
        "(includes the Python/JAX baseline, ~0.4 GB). Raw numbers: `docs/bench_env.json`.",
        "",
        "| preset | batch | backend | env-steps/s | agent-steps/s | JaxMARL env-steps/s "
        "| ours / JaxMARL | steps/call | compile s | peak RSS MB |",
        "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    rows, skipped = _throughput_rows(report)
    lines += rows
    if skipped:
        lines += ["", "Skipped:", ""] + [f"- {x}" for x in skipped]
    bd = report.get("breakdown")
    if bd and "parts" in bd:
        lines += _breakdown_table(bd)
    return "\n".join(lines) + "\n"


def _throughput_rows(report: dict[str, Any]) -> tuple[list[str], list[str]]:
    """The throughput table's rows (ours beside JaxMARL per preset and batch), and a line per
    skipped configuration."""
    s = report["settings"]
    res = {(r["impl"], r["preset"], r["batch"]): r for r in report["results"]}
    lines, skipped = [], []
    for preset in s["presets"]:
        for batch in s["batches"]:
            anchor = res.get(("jaxmarl", preset, batch), {})
            for impl in ("mjx", "kinematic"):
                row = res.get((impl, preset, batch))
                if row is None:
                    continue
                if row["status"] != "ok":
                    skipped.append(f"{impl} {preset} batch {batch}: {row['reason']}")
                    jm = _fmt(anchor["env_steps_per_s"]) if anchor.get("status") == "ok" else "-"
                    lines.append(f"| {preset} | {batch} | {impl} | skipped | | {jm} | | | | |")
                    continue
                lines.append(_throughput_row(preset, batch, impl, row, anchor))
            if anchor and anchor.get("status") != "ok":
                skipped.append(f"jaxmarl {preset} batch {batch}: {anchor['reason']}")
    return lines, skipped


def _throughput_row(preset: str, batch: int, impl: str, row: dict, anchor: dict) -> str:
    if anchor.get("status") == "ok":
        jm = _fmt(anchor["env_steps_per_s"])
        ratio = f"{row['env_steps_per_s'] / anchor['env_steps_per_s']:.2f}"
    else:
        jm, ratio = "-", "-"
    return (
        f"| {preset} | {batch} | {impl} | {_fmt(row['env_steps_per_s'])} | "
        f"{_fmt(row['agent_steps_per_s'])} | {jm} | {ratio} | "
        f"{row['steps_per_call']} | {row['compile_s']:.1f} | {row['peak_rss_mb']:.0f} |"
    )


def _breakdown_table(bd: dict[str, Any]) -> list[str]:
    """The breakdown's subsection: each part's time and its share of its backend's step."""
    lines = [
        "",
        f"### Where a step's time goes ({bd['preset']}, batch {bd['batch']})",
        "",
        "Each part jitted and `vmap`ped on its own, with its inputs precomputed as `step` "
        "hands them over (the geometry, offsets and distances, is computed once per step and "
        "shared by events, rewards, observations and masks); microseconds per batched call, "
        f"best of {bd['reps']} interleaved calls. Parts run alone lose some fusion (the "
        "geometry alone writes all its arrays out; in a step they are fused into their "
        "consumers), so they need not add up to the step; the rest of a step is glue (action "
        "lookup, freezing incapacitated agents, metrics, done flags). The rows 'before "
        "issue 9' are the same env code on the old MJX model (`implicitfast`, 5 ms actuator "
        "lag, 4 physics steps per control step), measured in the same run; their share is of "
        "the old MJX step.",
        "",
        "| part | us per call (best) | us (median) | share of kinematic step | share of MJX step |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    parts = bd["parts"]
    full = {b: parts[f"full step ({b})"]["us_best"] for b in ("kinematic", "mjx")}
    old_step = parts.get("full step (mjx, before issue 9)", {}).get("us_best")
    for name, row in parts.items():
        shares = []
        for b in ("kinematic", "mjx"):
            other = "mjx" if b == "kinematic" else "kinematic"
            total = full[b]
            if "before issue 9" in name:
                mine, total = b == "mjx", old_step
            else:
                mine = other not in name
            shares.append(f"{100 * row['us_best'] / total:.1f}%" if mine else "")
        lines.append(
            f"| {name} | {row['us_best']:,.0f} | {row['us_median']:,.0f} | "
            f"{shares[0]} | {shares[1]} |"
        )
    return lines


def write_markdown(path: Path, section: str) -> None:
    """Replaces this tool's section of `path` (or appends it); the rest of the file is kept."""
    if path.exists():
        text = path.read_text()
        start = text.find(SECTION)
        if start >= 0:
            nxt = text.find("\n## ", start + len(SECTION))
            end = len(text) if nxt < 0 else nxt + 1
            text = text[:start] + section + ("\n" if nxt >= 0 else "") + text[end:]
        else:
            text = text.rstrip("\n") + "\n\n" + section
    else:
        text = "# Benchmarks\n\n" + section
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


# ----------------------------------------------------------------------------- CLI


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="smoke run: small batches, few calls")
    ap.add_argument("--out", type=Path, help="JSON results (default docs/bench_env.json)")
    ap.add_argument("--markdown", type=Path, help="Markdown file (default docs/benchmarks.md)")
    ap.add_argument("--no-markdown", action="store_true", help="write no Markdown")
    ap.add_argument("--presets", nargs="+", default=list(PRESETS))
    ap.add_argument("--batches", nargs="+", type=int)
    ap.add_argument("--impls", nargs="+", choices=IMPLS, default=list(IMPLS))
    ap.add_argument("--steps", type=int, help="env steps per call, under lax.scan (default 20)")
    ap.add_argument("--actions", choices=("random", "fixed"), default="random")
    ap.add_argument("--min-calls", type=int, help="timed calls per configuration (default 5)")
    ap.add_argument("--min-seconds", type=float, default=3.0, help="timed seconds at least")
    ap.add_argument("--max-seconds", type=float, default=60.0, help="stop timing after this")
    ap.add_argument("--max-call-seconds", type=float, default=10.0, help="fewer steps beyond")
    ap.add_argument("--min-steps", type=int, default=5, help="fewest steps per call")
    ap.add_argument(
        "--jaxmarl-presets",
        nargs="+",
        default=["20-5-8"],
        help="presets JaxMARL runs at (at 240-60-120 its compile ran past 300 s)",
    )
    ap.add_argument(
        "--max-memory-gb", type=float, default=16.0, help="stop a worker past this resident size"
    )
    ap.add_argument(
        "--max-seconds-total", type=float, default=120.0, help="skip configs predicted longer"
    )
    ap.add_argument("--timeout", type=float, default=180.0, help="hard limit per configuration")
    ap.add_argument("--breakdown-batch", type=int, help="batch of the breakdown (default 256)")
    ap.add_argument("--breakdown-preset", default="20-5-8")
    ap.add_argument("--no-breakdown", action="store_true")
    args = ap.parse_args(argv)
    quick = args.quick
    if args.batches is None:
        args.batches = [1, 16] if quick else list(BATCHES)
    if args.steps is None:
        args.steps = 5 if quick else 20
    if args.min_calls is None:
        args.min_calls = 2 if quick else 5
    if quick:
        args.min_seconds = min(args.min_seconds, 0.5)
    if args.breakdown_batch is None:
        args.breakdown_batch = 16 if quick else 256
    if args.out is None:
        args.out = ROOT / ("results/bench_env_quick.json" if quick else "docs/bench_env.json")
    if args.markdown is None and not quick and not args.no_markdown:
        args.markdown = ROOT / "docs/benchmarks.md"
    if args.no_markdown:
        args.markdown = None
    for name in ("steps", "min_calls", "breakdown_batch"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if any(b < 1 for b in args.batches):
        ap.error("--batches must all be >= 1")
    from pe_mjx.config import PRESETS as KNOWN

    for preset in [*args.presets, *args.jaxmarl_presets, args.breakdown_preset]:
        if preset not in KNOWN:
            ap.error(f"unknown preset {preset!r}; known: {', '.join(KNOWN)}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    start = time.perf_counter()
    report: dict[str, Any] = {"machine": machine_info()}
    report["settings"] = {
        "presets": args.presets,
        "batches": args.batches,
        "impls": args.impls,
        "steps_per_call": args.steps,
        "max_call_seconds": args.max_call_seconds,
        "jaxmarl_presets": args.jaxmarl_presets,
        "actions": args.actions,
        "min_calls": args.min_calls,
        "min_seconds": args.min_seconds,
        "max_memory_gb": args.max_memory_gb,
        "max_seconds_total": args.max_seconds_total,
        "timeout_s": args.timeout,
        "quick": args.quick,
        "throughput": "best timed call (median also given); calls after a warm-up call",
        "memory": (
            "peak_rss_mb: resource.getrusage(RUSAGE_SELF).ru_maxrss of the worker subprocess "
            "that runs only this configuration (includes the Python/JAX/XLA baseline); "
            "baseline_rss_mb: the same before compiling the rollout"
        ),
        "compile": "jax.jit(rollout).lower(...).compile() wall time",
    }
    report.update(collect(args))
    if not args.no_breakdown:
        spec = {
            "impl": "breakdown",
            "preset": args.breakdown_preset,
            "batch": args.breakdown_batch,
            "reps": 10 if args.quick else 50,
        }
        print("[bench_env] breakdown ...", flush=True)
        report["breakdown"] = run_worker(spec, args.timeout, args.max_memory_gb)
    report["total_seconds"] = round(time.perf_counter() - start, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"[bench_env] wrote {args.out}")
    if args.markdown:
        write_markdown(args.markdown, markdown(report))
        print(f"[bench_env] wrote {args.markdown}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
