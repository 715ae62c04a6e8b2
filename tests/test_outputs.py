"""pe_mjx/outputs.py: one way to write an output (never a device node or a FIFO, never an
existing file without --force, never half-written) and one way to read an input (capped)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from pe_mjx import outputs
from pe_mjx.outputs import OutputError

CLI = str(Path(sys.executable).parent / "pe-mjx")


def _cli(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([CLI, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)


def _one_error_line(result: subprocess.CompletedProcess, *words: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pe-mjx: error: "), result.stderr
    for word in words:
        assert word in lines[0], lines[0]


def _temporaries(directory: Path) -> list[str]:
    return [p.name for p in directory.iterdir() if outputs.TEMP_MARK in p.name]


def test_a_device_node_a_fifo_or_a_directory_is_never_a_target_even_with_force(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for target, kind in ((Path("/dev/null"), "a device"), (fifo, "FIFO"), (tmp_path, "directory")):
        with pytest.raises(OutputError, match=kind):
            outputs.check_target(target, force=True, flag="-o")
        with pytest.raises(OutputError, match=kind):
            outputs.write_file(target, "x", force=True)
    assert not _temporaries(tmp_path)
    with pytest.raises(OutputError, match="not a directory"):
        outputs.check_target(Path("/dev/null"), flag="--out", directory=True)


def test_an_existing_file_needs_force_and_is_replaced_whole(tmp_path):
    target = tmp_path / "figure.png"
    target.write_bytes(b"the user's own file")
    with pytest.raises(OutputError, match=r"-o: .*figure.png exists; pass --force"):
        outputs.write_file(target, b"new", flag="-o")
    assert target.read_bytes() == b"the user's own file"
    outputs.write_file(target, b"new", force=True)
    assert target.read_bytes() == b"new"
    assert not _temporaries(tmp_path)


def test_an_interrupted_or_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "anim.gif"
    target.write_bytes(b"old")

    def half(path: Path, error: BaseException) -> None:
        path.write_bytes(b"half of a GIF")
        raise error

    for error in (KeyboardInterrupt(), OSError(28, "No space left on device")):
        with pytest.raises(type(error)):
            outputs.write_file(target, lambda p, e=error: half(p, e), force=True)
        assert target.read_bytes() == b"old"
        assert not _temporaries(tmp_path)
    with outputs.writing(target, force=True) as tmp:  # the suffix is kept (matplotlib, imageio)
        assert tmp.suffix == ".gif" and tmp.parent == tmp_path
        tmp.write_bytes(b"GIF89a")
    assert target.read_bytes() == b"GIF89a"


def test_stale_temporaries_of_dead_processes_are_cleaned_those_of_live_ones_kept(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    pid = int(dead.stdout)
    stale_file = tmp_path / f".a.png{outputs.TEMP_MARK}{pid}-0123abcd.png"
    stale_dir = tmp_path / f".results{outputs.TEMP_MARK}{pid}-89abcdef"
    live = tmp_path / f".b.png{outputs.TEMP_MARK}{os.getpid()}-0123abcd.png"
    unrelated = tmp_path / ".a.png.tmp"
    stale_file.write_text("x")
    (stale_dir / "trajectories").mkdir(parents=True)
    live.write_text("x")
    unrelated.write_text("x")
    outputs.write_file(tmp_path / "c.txt", "c")  # a write into the directory cleans it
    assert not stale_file.exists() and not stale_dir.exists()
    assert live.exists() and unrelated.exists()


def test_a_directory_output_appears_whole_or_not_at_all_even_under_kill_9(tmp_path):
    """A process killed (SIGKILL) while building the output leaves no `out` (and its old one as
    it was); the next write there removes the killed one's temporary."""
    script = textwrap.dedent(
        """
        import os, signal, sys
        from pathlib import Path
        from pe_mjx import outputs
        with outputs.writing_dir(Path(sys.argv[1])) as stage:
            (stage / "results.json").write_text("{}")
            (stage / "trajectories").mkdir()
            os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    for existing in (False, True):
        out = tmp_path / f"results-{existing}"
        if existing:
            out.mkdir()
            (out / "notes.txt").write_text("the user's")
        proc = subprocess.run([sys.executable, "-c", script, str(out)], timeout=120)
        assert proc.returncode == -signal.SIGKILL
        assert out.exists() == existing
        if existing:
            assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
        assert _temporaries(tmp_path)  # the killed process's, until the next write
    with outputs.writing_dir(tmp_path / "results-True") as stage:
        (stage / "results.json").write_text("{}")
    assert not _temporaries(tmp_path)
    # The user's file is kept beside the new output (the same file: a hard link).
    out = tmp_path / "results-True"
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "results.json"]
    assert (out / "notes.txt").read_text() == "the user's"


def test_evaluate_builds_its_results_beside_out_and_leaves_nothing_on_failure(
    tmp_path, monkeypatch
):
    from pe_mjx import evaluate
    from pe_mjx.config import get_preset
    from pe_mjx.eval_config import EvalConfig

    seen: list[Path] = []

    def half_then_fail(config, stage, log, progress, keep):
        seen.append(stage)
        (stage / "results.md").write_text("half")
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluate, "_evaluate_into", half_then_fail)
    config = EvalConfig(env=get_preset("2-1-1"), trials=2, backend="kinematic")
    out = tmp_path / "res"
    with pytest.raises(KeyboardInterrupt):
        evaluate.run_evaluation(config, out, log=lambda _: None)
    assert seen and seen[0].parent == tmp_path and outputs.TEMP_MARK in seen[0].name
    assert not out.exists() and not _temporaries(tmp_path)


def test_reads_are_capped_for_devices_and_fifos(tmp_path):
    tic = time.monotonic()
    # A device is refused before a byte is read (/dev/zero filled the whole cap first).
    with pytest.raises(OutputError, match=r"--config: /dev/zero is a device, not a file"):
        outputs.read_bytes("/dev/zero", 1000, flag="--config")
    (tmp_path / "big.json").write_bytes(b" " * 1001)
    with pytest.raises(OutputError, match=r"big.json: larger than 1,000 bytes"):
        outputs.read_bytes(tmp_path / "big.json", 1000)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert outputs.read_bytes(fifo, 1000) == b""  # no writer: empty, no wait
    # A pipe says no size: read up to the cap, then refused (its write end stays open here).
    read_end, write_end = os.pipe()
    try:
        os.write(write_end, b"x" * 5000)
        with pytest.raises(OutputError, match=r"larger than 1,000 bytes"):
            outputs.read_bytes(f"/proc/self/fd/{read_end}", 1000)
    finally:
        os.close(read_end)
        os.close(write_end)
    assert time.monotonic() - tic < 5
    (tmp_path / "ok.txt").write_text("é")
    assert outputs.read_text(tmp_path / "ok.txt", 10) == "é"
    (tmp_path / "bin").write_bytes(b"\xff\xfe")
    with pytest.raises(OutputError, match="not UTF-8"):
        outputs.read_text(tmp_path / "bin", 10)


def test_scene_and_export_refuse_a_device_node_even_with_force(tmp_path):
    scene = _cli("scene", "--preset", "2-1-1", "-o", "/dev/null", "--force", cwd=tmp_path)
    _one_error_line(scene, "/dev/null", "device")
    export = _cli("export", "mix-20-5-8", "-o", "/dev/null", "--force", cwd=tmp_path)
    _one_error_line(export, "/dev/null", "device")
    os.mkfifo(tmp_path / "pipe.xml")
    fifo = _cli("scene", "--preset", "2-1-1", "-o", "pipe.xml", "--force", cwd=tmp_path)
    _one_error_line(fifo, "pipe.xml", "FIFO")


def test_plot_never_overwrites_an_unrelated_file_without_force(tmp_path):
    from tensorboardX import SummaryWriter

    run = tmp_path / "run"
    writer = SummaryWriter(str(run / "tb"))
    for step in (100, 200):
        writer.add_scalar("eval/pursuer_vs_scripted/success_rate", step / 400, step)
    writer.close()
    mine = tmp_path / "existing.png"
    mine.write_bytes(b"a picture of the user's")
    refused = _cli("plot", str(run), "-o", str(mine), cwd=tmp_path)
    _one_error_line(refused, "existing.png", "--force")
    assert mine.read_bytes() == b"a picture of the user's"
    forced = _cli("plot", str(run), "-o", str(mine), "--force", cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert mine.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not _temporaries(tmp_path)


def test_reproduce_skip_train_without_runs_is_an_error_and_keeps_docs(tmp_path):
    docs = tmp_path / "paper_tables.md"
    docs.write_text("# the tables of a long reproduction\n")
    args = ["--skip-train", "--runs", str(tmp_path / "none"), "--docs", str(docs)]
    result = _cli("reproduce", *args, "--out", str(tmp_path / "out"), cwd=tmp_path)
    _one_error_line(result, "--runs", "paper_tables.md")
    assert docs.read_text() == "# the tables of a long reproduction\n"
