"""The compact curves file: what the trainer logs, readable back, bounded, resumable."""

from __future__ import annotations

import gzip
import lzma

import pytest

from pe_mjx.ppo.curves import (
    CURVES_FILE,
    LEGACY_FILE,
    CurveLog,
    CurvesError,
    curves_file,
    read_rows,
    scalars,
    training_time,
    write_rows,
)


def test_rows_round_trip_with_gaps_and_non_finite_values(tmp_path):
    log = CurveLog(tmp_path, resume_at=None)
    log.add(100, {"loss/a": 1.5, "loss/b": float("nan")})
    log.add(200, {"loss/a": 2.25, "eval/x": 0.5, "loss/b": float("inf")})
    log.flush()
    rows = read_rows(tmp_path / CURVES_FILE)
    assert [r["env_steps"] for r in rows] == [100, 200]
    assert scalars(rows) == {"loss/a": [(100, 1.5), (200, 2.25)], "eval/x": [(200, 0.5)]}
    with lzma.open(tmp_path / CURVES_FILE, "rt") as f:  # plain xz: pandas reads it as it is
        header = f.readline().strip().split(",")
    assert header == ["env_steps", "wall_time", "eval/x", "loss/a"]
    before = (tmp_path / CURVES_FILE).read_bytes()
    write_rows(tmp_path / CURVES_FILE, rows)  # the same rows, the same bytes (no time stamp)
    assert (tmp_path / CURVES_FILE).read_bytes() == before


def test_a_run_written_as_gzip_is_read_and_resumed_into_one_xz_file(tmp_path):
    """Runs from before the xz format keep a curves.csv.gz: plotted and summarised as they are,
    and a resumed run rewrites its points as curves.csv.xz and drops the gzip file."""
    text = b"env_steps,wall_time,v\n100,1.0,1\n200,2.0,2\n300,3.0,3\n"
    (tmp_path / LEGACY_FILE).write_bytes(gzip.compress(text))
    assert curves_file(tmp_path) == tmp_path / LEGACY_FILE
    assert scalars(read_rows(curves_file(tmp_path)))["v"] == [(100, 1.0), (200, 2.0), (300, 3.0)]
    resumed = CurveLog(tmp_path, resume_at=200)
    resumed.add(300, {"v": 30.0})
    resumed.flush()
    assert sorted(p.name for p in tmp_path.iterdir()) == [CURVES_FILE]
    assert curves_file(tmp_path) == tmp_path / CURVES_FILE
    assert scalars(read_rows(tmp_path / CURVES_FILE))["v"] == [(100, 1.0), (200, 2.0), (300, 30.0)]


def test_diagnostics_keep_4_digits_and_episode_and_eval_tags_6(tmp_path):
    value = 0.123456789
    tags = ["loss/p/kl", "reward/e/flee", "perf/sps", "ppo/p/lr", "episode/length", "eval/x/y"]
    row = {"env_steps": 1, "wall_time": 0.0, **dict.fromkeys(tags, value)}
    write_rows(tmp_path / CURVES_FILE, [row])
    (row,) = read_rows(tmp_path / CURVES_FILE)
    assert {t: row[t] for t in tags} == {
        **dict.fromkeys(tags[:4], 0.1235),
        **dict.fromkeys(tags[4:], 0.123457),
    }


def test_resume_drops_the_points_logged_after_the_checkpoint(tmp_path):
    log = CurveLog(tmp_path, resume_at=None)
    for step in (100, 200, 300):
        log.add(step, {"v": step / 100})
    log.flush()
    resumed = CurveLog(tmp_path, resume_at=200)  # the checkpoint was at 200 env steps
    resumed.add(300, {"v": 30.0})
    resumed.flush()
    assert scalars(read_rows(tmp_path / CURVES_FILE))["v"] == [(100, 1.0), (200, 2.0), (300, 30.0)]
    fresh = CurveLog(tmp_path, resume_at=None)  # a fresh run in the same directory starts empty
    fresh.add(50, {"v": 0.0})
    fresh.flush()
    assert scalars(read_rows(tmp_path / CURVES_FILE))["v"] == [(50, 0.0)]


@pytest.mark.parametrize(
    "content",
    [
        b"not xz at all",
        b"step,value\n1,2\n",
        b"env_steps,wall_time,v\n1,2\n",
        b"env_steps,wall_time,v\n1,2,abc\n",
        b"env_steps,wall_time,v\n1,2,3\n",
        b"env_steps,wall_time,v\n1e400,2,3\n",
        b"env_steps,wall_time,v\n1,2,nan\n",
        b"env_steps,wall_time,v\n-5,2,3\n",
        b"env_steps,wall_time,v\n1.5,2,3\n",
    ],
    # The writer never writes nan, inf or a fractional step (`_cell`): 1e400 steps was an
    # OverflowError traceback, the others a plot of nonsense.
    ids=[
        "not-xz",
        "no-env-steps",
        "short-row",
        "not-a-number",
        "truncated",
        "inf-steps",
        "nan-value",
        "negative-steps",
        "fractional-steps",
    ],
)
def test_damaged_files_are_one_clear_error(tmp_path, content):
    """Each damage in the xz file of today's runs and in the gzip one of older runs. (The
    compressed bytes are made in the test, not in the parameters: a gzip header holds the time
    of day, and two test workers that collected a second apart disagreed on the test ids.)"""
    for name, compress in ((CURVES_FILE, lzma.compress), (LEGACY_FILE, gzip.compress)):
        path = tmp_path / name
        if content.startswith(b"not xz"):
            path.write_bytes(content)
        elif content.endswith(b"1,2,3\n"):
            path.write_bytes(compress(content)[:-6])
        else:
            path.write_bytes(compress(content))
        with pytest.raises(CurvesError, match=name):
            read_rows(path)


def test_a_decompression_bomb_is_refused_before_it_is_read_whole(tmp_path, monkeypatch):
    from pe_mjx.ppo import curves

    monkeypatch.setattr(curves, "MAX_BYTES", 1000)
    path = tmp_path / CURVES_FILE
    for name, compress in ((CURVES_FILE, lzma.compress), (LEGACY_FILE, gzip.compress)):
        path = tmp_path / name
        path.write_bytes(compress(b"env_steps,v\n" + b"1,2\n" * 10_000))
        assert path.stat().st_size < 1000
        with pytest.raises(CurvesError, match="larger than"):
            read_rows(path)


def test_a_pause_between_resumed_chunks_counts_as_one_median_interval():
    # two chunks of 6-minute iterations, one with a 9-minute evaluation, 5 hours apart
    first = [0.0, 360.0, 720.0, 1260.0, 1620.0]
    times = first + [1620.0 + 5 * 3600 + 360.0 * i for i in range(3)]
    rows = [{"env_steps": 2048 * (i + 1), "wall_time": t} for i, t in enumerate(times)]
    time = training_time(rows)
    assert (time["pauses"], time["median_interval_s"], time["longest_counted_s"]) == (1, 360, 540)
    # six intervals counted (2,340 s) and the pause as one median interval
    assert time["hours"] == 0.75
    assert time["paused_h"] == 5.0
    assert time["env_steps"] == 8 * 2048
