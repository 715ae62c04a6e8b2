"""pe_mjx/sizes.py: counts, batches and trials are checked against the memory they need before
anything allocates; files are read with a cap; error messages never print an unbounded value."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pe_mjx import sizes

CLI = str(Path(sys.executable).parent / "pe-mjx")


def _cli(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([CLI, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)


def _one_error_line(result: subprocess.CompletedProcess, *words: str) -> str:
    assert result.returncode == 2, result.stderr[-3000:]
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pe-mjx: error: "), result.stderr[-3000:]
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def test_an_absurd_num_envs_in_a_config_file_is_one_line_before_any_allocation(tmp_path):
    """`ppo.num_envs: 1000000000` stalled in native code for 12+ minutes, Ctrl-C ignored."""
    config = tmp_path / "big.yaml"
    config.write_text("ppo:\n  num_envs: 1000000000\n")
    result = _cli("train", "--config", str(config), "--out", str(tmp_path / "run"), cwd=tmp_path)
    _one_error_line(result, "ppo.num_envs", "memory")
    assert not (tmp_path / "run").exists()


def test_the_size_checks_take_well_under_a_second_and_pass_sane_sizes(monkeypatch):
    from pe_mjx.config import get_preset
    from pe_mjx.experiment import default_config

    config = default_config("20-5-8")
    big = config.replace(ppo=dataclasses.replace(config.ppo, num_envs=1_000_000_000))
    tic = time.perf_counter()
    sizes.check_training(config)  # the defaults fit this machine
    with pytest.raises(sizes.SizeError, match=r"ppo.num_envs 1,000,000,000 .* TB"):
        sizes.check_training(big)
    with pytest.raises(sizes.SizeError, match="--record"):
        sizes.check_evaluation(get_preset("20-5-8"), 100, 10**9)
    # (EnvConfig's own placement check refuses 10**9 agents in a preset's arena; any scene
    # object with the counts is checked here.)
    huge_scene = SimpleNamespace(
        pursuer=SimpleNamespace(num_agents=10**9),
        evader=SimpleNamespace(num_agents=1),
        arena=SimpleNamespace(num_obstacles=1),
        max_steps=1000,
    )
    with pytest.raises(sizes.SizeError, match="1000000000 pursuers"):
        sizes.check_evaluation(huge_scene, 1, 0)
    assert time.perf_counter() - tic < 1.0
    # A small machine (PE_MJX_MEMORY_BYTES states its memory): the defaults no longer fit.
    monkeypatch.setenv("PE_MJX_MEMORY_BYTES", "1000000")
    with pytest.raises(sizes.SizeError, match=r"more than the 1.0 MB available"):
        sizes.check_training(config)


@pytest.mark.parametrize("stated", ["inf", "1e400", "-5", "0", "nan", "lots"])
def test_a_stated_memory_that_is_not_a_number_of_bytes_is_one_line_naming_it(stated, monkeypatch):
    """ "inf" was an OverflowError traceback, "-5" blamed the flag whose size then did not fit in
    0 bytes, and "lots" was ignored without a word."""
    from pe_mjx.config import get_preset

    monkeypatch.setenv("PE_MJX_MEMORY_BYTES", stated)
    with pytest.raises(sizes.SizeError, match=r"^PE_MJX_MEMORY_BYTES must be a positive number"):
        sizes.check_scene(get_preset("2-1-1"))


def test_evaluate_refuses_trials_that_cannot_fit_before_writing(tmp_path, monkeypatch):
    from pe_mjx.config import get_preset
    from pe_mjx.eval_config import EvalConfig
    from pe_mjx.evaluate import run_evaluation

    monkeypatch.setenv("PE_MJX_MEMORY_BYTES", "100000")
    config = EvalConfig(env=get_preset("4-1-2"), trials=1000, backend="kinematic")
    with pytest.raises(sizes.SizeError, match="--trials 1,000"):
        run_evaluation(config, tmp_path / "res", log=lambda _: None)
    assert list(tmp_path.iterdir()) == []


def test_config_from_dev_zero_is_one_line_not_a_read_that_never_ends(tmp_path):
    result = _cli("train", "--config", "/dev/zero", cwd=tmp_path, timeout=120)
    _one_error_line(result, "--config", "/dev/zero", "is a device")


def _alias_bomb(levels: int = 9, width: int = 9) -> str:
    """YAML whose last anchor expands to width**levels strings (387 million here)."""
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return "\n".join(lines) + f"\nppo:\n  num_envs: *a{levels - 1}\n"


def test_a_yaml_alias_bomb_is_never_expanded_by_the_error_message(tmp_path):
    from pe_mjx.experiment import read_config_file

    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(_alias_bomb())
    tic = time.perf_counter()
    with pytest.raises(ValueError) as err:
        read_config_file(bomb)
    assert time.perf_counter() - tic < 5
    assert len(str(err.value)) < 400, str(err.value)[:1000]
    # Inside a known field too (the anchors nested in the value itself).
    nested = "ppo:\n  num_envs: &b ["
    nested += ", ".join(["&c [" + ", ".join(['"x"'] * 9) + "]"] + ["*c"] * 8) + "]\n"
    nested += "  unroll_length: [" + ", ".join(["*b"] * 9) + "]\n"
    (tmp_path / "nested.yaml").write_text(nested)
    with pytest.raises(ValueError) as err:
        read_config_file(tmp_path / "nested.yaml")
    assert len(str(err.value)) < 400 and "num_envs" in str(err.value), str(err.value)[:1000]


def test_shorten_bounds_any_value():
    deep: list = ["x"] * 9
    for _ in range(12):
        deep = [deep] * 9  # 9**12 leaves if expanded
    tic = time.perf_counter()
    text = sizes.shorten(deep)
    assert len(text) <= 120 and time.perf_counter() - tic < 1
    long = sizes.shorten("a" * 10_000)
    assert len(long) <= 120 and "..." in long
    assert sizes.shorten(3) == "3"


def _scipy_ratio_ci(num: np.ndarray, den: np.ndarray, seed: int) -> tuple[float, float]:
    """The bootstrap as it was: every resample in one vectorised batch."""
    from scipy import stats

    def mean_ratio(n, d, axis=-1):
        n_mean, d_mean = n.mean(axis=axis), d.mean(axis=axis)
        return np.where(d_mean > 0, n_mean / np.maximum(d_mean, 1e-12), np.inf)

    with np.errstate(invalid="ignore"):
        ci = stats.bootstrap(
            (num, den), mean_ratio, paired=True, vectorized=True, method="percentile",
            n_resamples=2000, rng=np.random.default_rng(seed),
        ).confidence_interval  # fmt: skip
    return float(ci.low), float(ci.high)


def test_the_bootstrap_of_the_trial_cap_takes_bounded_memory_and_the_same_numbers():
    """--trials 100000 (the cap) needed 5.5 GB for its bootstrap; in batches it takes ~100 MB
    and gives the numbers of the single batch for the same seed."""
    from pe_mjx.eval_config import MAX_TRIALS
    from pe_mjx.eval_metrics import ratio_ci

    rng = np.random.default_rng(3)
    num, den = rng.integers(0, 5, 3000).astype(float), rng.integers(0, 3, 3000).astype(float)
    _, low, high = ratio_ci(num, den, seed=7)
    assert (low, high) == _scipy_ratio_ci(num, den, 7)
    num, den = rng.integers(0, 5, MAX_TRIALS).astype(float), rng.integers(0, 3, MAX_TRIALS)
    tracemalloc.start()
    try:
        ratio, low, high = ratio_ci(num, den.astype(float), seed=0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert low <= ratio <= high
    assert peak < 400e6, f"{peak / 1e6:.0f} MB"


def test_view_export_steps_are_checked_against_the_recording_memory(tmp_path):
    """`pe-mjx view --export` keeps every recorded frame: an absurd --steps is one line."""
    result = _cli(
        "view", "--preset", "20-5-8", "--backend", "kinematic", "--export",
        str(tmp_path / "rec"), "--steps", str(10**13), cwd=tmp_path,
    )  # fmt: skip
    _one_error_line(result, "--steps", "memory")
    assert list(tmp_path.iterdir()) == []
