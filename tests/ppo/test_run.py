"""The training loop's loggers: Weights & Biases (offline) beside TensorBoard; W&B missing."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from pe_mjx.cli import main
from pe_mjx.plots import _tensorboard_scalars, read_scalars
from pe_mjx.ppo.curves import DIAGNOSTIC_PREFIXES

TRAIN_2_ITERATIONS = [
    *("--preset", "2-1-1", "--backend", "kinematic", "--no-progress"),
    *("--ppo.num-envs", "8", "--ppo.unroll-length", "8", "--env-steps", "128"),
    *("--ppo.update-epochs", "1", "--ppo.num-minibatches", "2"),
    *("--eval-every", "2", "--eval-envs", "2", "--checkpoint-every", "2"),
    *("--pursuer.network.width", "16", "--pursuer.network.hidden", "32"),
    *("--evader.network.width", "16", "--evader.network.hidden", "32"),
]


def wandb_history(run_file: Path) -> list[dict[str, float]]:
    """The `history` records (one `wandb.log` call each) of an offline run's `.wandb` file.

    The file is a LevelDB-style log (a 7-byte header, then 32 KiB blocks of records, each with
    a 7-byte header: crc32, length, type full/first/middle/last) of `wandb.proto` Records.
    """
    from wandb.proto import wandb_internal_pb2

    raw = run_file.read_bytes()
    assert raw[:4] == b":W&B", raw[:16]
    block, pos, records, partial = 32768, 7, [], b""
    while pos + 7 <= len(raw):
        left = block - pos % block
        if left < 7:  # a block's tail too short for a header is padding
            pos += left
            continue
        _, length, kind = struct.unpack("<IHB", raw[pos : pos + 7])
        if length == kind == 0:  # zero padding to the end of the block
            pos += left
            continue
        data, pos = raw[pos + 7 : pos + 7 + length], pos + 7 + length
        if kind == 1:
            records.append(data)
        elif kind == 2:
            partial = data
        elif kind == 3:
            partial += data
        elif kind == 4:
            records.append(partial + data)
    history = []
    for data in records:
        record = wandb_internal_pb2.Record()
        record.ParseFromString(data)
        if record.WhichOneof("record_type") == "history":
            items = record.history.item
            history.append(
                {i.key or "/".join(i.nested_key): json.loads(i.value_json) for i in items}
            )
    return history


def test_wandb_offline_run_holds_the_logged_scalars(tmp_path):
    env = dict(os.environ, WANDB_MODE="offline", WANDB_SILENT="true")
    for var in ("WANDB_CONFIG_DIR", "WANDB_CACHE_DIR", "WANDB_DATA_DIR"):
        env[var] = str(tmp_path / "wandb-home")
    cmd = [sys.executable, "-m", "pe_mjx.cli", "train", *TRAIN_2_ITERATIONS]
    result = subprocess.run(
        [*cmd, "--wandb-project", "pe-mjx-test", "--out", "run"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    # Without the progress bar the compiles are announced on stderr.
    assert "2-1-1: compiling the training iteration..." in result.stderr
    assert "2-1-1: compiling the evaluation..." in result.stderr
    (run_file,) = (tmp_path / "run" / "wandb").glob("offline-run-*/run-*.wandb")
    history = wandb_history(run_file)
    assert [h["_step"] for h in history] == [64, 128]  # one log per iteration, x = env steps
    for h in history:
        for team in ("pursuer", "evader"):
            for tag in (f"loss/{team}/policy_loss", f"reward/{team}/total"):
                assert tag in h, sorted(h)
            assert h[f"ppo/{team}/learning_rate"] >= 0
    last = history[-1]
    for team in ("pursuer", "evader"):
        assert f"eval/{team}_vs_scripted/{team}_return" in last
    # Every scalar W&B holds is the one TensorBoard holds, and the compact curves (6 digits, 4
    # for the training diagnostics).
    tensorboard = _tensorboard_scalars(tmp_path / "run")
    curves = read_scalars(tmp_path / "run")
    for h in history:
        for tag, value in h.items():
            if not tag.startswith("_"):
                assert dict(tensorboard[tag])[h["_step"]] == pytest.approx(value, rel=1e-6), tag
                rel = 1e-3 if tag.startswith(DIAGNOSTIC_PREFIXES) else 1e-5
                assert dict(curves[tag])[h["_step"]] == pytest.approx(value, rel=rel), tag


def test_wandb_project_without_the_extra_is_one_error_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "wandb", None)  # `import wandb` raises ImportError
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(["train", *TRAIN_2_ITERATIONS, "--wandb-project", "x", "--out", "run"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err == (
        "pe-mjx: error: --wandb-project needs Weights & Biases: pip install 'pe-mjx[wandb]'\n"
    )
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_the_start_history_of_a_run_survives_old_and_damaged_config_files(tmp_path):
    from pe_mjx.ppo.run_files import MAX_CONFIG_BYTES, _earlier_starts

    path = tmp_path / "config.json"
    assert _earlier_starts(tmp_path) == []  # no file yet
    version = {"pe_mjx": "0.1.0", "git_commit": "abc"}
    # Written before `starts` existed: its one code version, iteration unknown.
    path.write_text(json.dumps({"code_version": version}))
    assert _earlier_starts(tmp_path) == [{"iteration": None, "code_version": version}]
    starts = [{"iteration": 0, "code_version": version}, {"iteration": "2"}, 7]
    path.write_text(json.dumps({"code_version": version, "starts": starts}))
    assert _earlier_starts(tmp_path) == starts[:1]  # malformed entries dropped
    for damaged in ("{not json", "[1, 2]", json.dumps({"starts": "x"})):
        path.write_text(damaged)
        assert _earlier_starts(tmp_path) == []
    path.write_text(" " * (MAX_CONFIG_BYTES + 1))  # never read whole
    assert _earlier_starts(tmp_path) == []
