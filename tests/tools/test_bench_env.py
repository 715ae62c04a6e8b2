"""tools/bench_env.py without running a benchmark: skip predictions, Markdown, CLI errors."""

from __future__ import annotations

import pytest

from tests.tool_modules import load_tool


@pytest.fixture(scope="module")
def bench():
    return load_tool("bench_env")


def _row(batch, peak, best, steps=20, compile_s=5.0, impl="kinematic", preset="20-5-8"):
    return {
        "impl": impl,
        "preset": preset,
        "batch": batch,
        "status": "ok",
        "agents": 25,
        "steps_per_call": steps,
        "calls": 5,
        "env_steps_per_s": batch * steps / best,
        "agent_steps_per_s": 25 * batch * steps / best,
        "env_steps_per_s_median": batch * steps / best,
        "seconds_per_call_best": best,
        "compile_s": compile_s,
        "baseline_rss_mb": 400.0,
        "peak_rss_mb": peak,
    }


def test_predict_extrapolates_memory_and_shortens_long_calls(bench):
    args = bench.parse_args([])
    assert bench.predict([], 16, args) == {}
    one = _row(1, peak=500.0, best=0.01)
    # One point: everything above the baseline scales with the batch.
    assert bench.predict([one], 16, args)["memory_mb"] == pytest.approx(500 + 100 * 15)
    # Two points: their slope.
    two = _row(16, peak=530.0, best=0.16)
    guess = bench.predict([one, two], 256, args)
    assert guess["memory_mb"] == pytest.approx(530 + 2 * 240)
    assert guess["steps"] == args.steps  # 2.56 s per call: no need to shorten
    # A call that would take 0.5 ms * 4096 * 20 = 41 s gets fewer steps (at least --min-steps).
    slow = _row(256, peak=900.0, best=0.5e-3 * 256 * 20)
    guess = bench.predict([two, slow], 4096, args)
    assert guess["steps"] == args.min_steps
    assert guess["seconds_per_call"] == pytest.approx(0.5e-3 * 4096 * args.min_steps)


def test_write_markdown_replaces_only_its_section(bench, tmp_path):
    path = tmp_path / "benchmarks.md"
    bench.write_markdown(path, bench.SECTION + "\n\nfirst\n")
    assert path.read_text() == "# Benchmarks\n\n" + bench.SECTION + "\n\nfirst\n"
    path.write_text("# Benchmarks\n\n## Networks\n\nkeep me\n")
    bench.write_markdown(path, bench.SECTION + "\n\nsecond\n")
    bench.write_markdown(path, bench.SECTION + "\n\nthird\n")
    text = path.read_text()
    assert "keep me" in text and "third" in text and "second" not in text
    path.write_text(f"# B\n\n{bench.SECTION}\n\nold\n\n## Later\n\nkeep too\n")
    bench.write_markdown(path, bench.SECTION + "\n\nnew\n")
    text = path.read_text()
    assert "old" not in text and "new" in text and text.endswith("## Later\n\nkeep too\n")


def test_markdown_renders_results_ratios_and_skips(bench):
    ours = _row(256, peak=600.0, best=0.1)
    anchor = {**_row(256, peak=700.0, best=0.2), "impl": "jaxmarl"}
    skipped = {
        "impl": "mjx",
        "preset": "20-5-8",
        "batch": 256,
        "status": "skipped",
        "reason": "predicted peak memory 20.0 GB > 16 GB",
    }
    report = {
        "machine": {
            "date": "2026-01-01T00:00:00+00:00",
            "cpu_model": "test CPU",
            "cpu_cores": 2,
            "memory_gb": 8.0,
            "jax": "0",
            "jax_backend": "cpu",
            "mujoco": "0",
            "jaxmarl": "0.2.0",
            "load_average_at_start": [1.0, 1.0, 1.0],
        },
        "settings": {
            "presets": ["20-5-8"],
            "batches": [256],
            "actions": "random",
            "jaxmarl_presets": ["20-5-8"],
        },
        "results": [anchor, ours, skipped],
    }
    text = bench.markdown(report)
    assert text.startswith(bench.SECTION)
    assert "| 20-5-8 | 256 | kinematic | 51,200 |" in text
    assert "| 2.00 |" in text  # ours / JaxMARL
    assert "mjx 20-5-8 batch 256: predicted peak memory" in text


@pytest.mark.parametrize(
    "argv",
    [["--presets", "no-such-preset"], ["--batches", "0"], ["--steps", "0"]],
)
def test_bad_arguments_exit_with_a_message(bench, argv, capsys):
    with pytest.raises(SystemExit) as err:
        bench.parse_args(argv)
    assert err.value.code == 2
    assert "error" in capsys.readouterr().err


def test_worker_over_the_memory_limit_is_stopped_with_the_measured_size(bench):
    """Memory is measured, not predicted: a worker past --max-memory-gb (here 50 MB, which the
    Python/JAX import alone exceeds) is stopped and recorded with what it reached."""
    spec = {"impl": "kinematic", "preset": "2-1-1", "batch": 1, "steps": 1, "actions": "random"}
    spec.update(min_calls=1, min_seconds=0.0, max_seconds=1.0)
    row = bench.run_worker(spec, timeout=120.0, max_memory_gb=0.05)
    assert row["status"] == "skipped"
    assert "measured" in row["reason"] and "--max-memory-gb 0.05" in row["reason"]
