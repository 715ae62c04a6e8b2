"""The wheel is whole: built, installed into a fresh venv (reusing this venv's dependencies), it
runs `pe-mjx view --help`, loads the shipped policy by name and evaluates it."""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd: list[str], cwd: Path, **kw) -> subprocess.CompletedProcess:
    out = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=900, **kw)
    assert out.returncode == 0, f"{cmd}\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}"
    return out


def test_wheel_installs_whole(tmp_path):
    # Build from a copy: an in-tree build would leave build/ and egg-info behind.
    src = tmp_path / "src"
    files = _run(["git", "ls-files", "-co", "--exclude-standard"], ROOT).stdout.split("\n")
    for name in filter(None, files):
        path = ROOT / name
        if path.is_file() and not name.startswith(("tests/", "docs/", "tools/", "train/")):
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes(path.read_bytes())
    wheels = tmp_path / "wheels"
    # No build isolation: the dev extra installs setuptools>=77 here, and it works offline.
    pip = [sys.executable, "-m", "pip"]
    _run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", wheels, src], tmp_path)
    (wheel,) = wheels.glob("pe_mjx-*.whl")

    # A fresh venv that sees this venv's packages through a .pth file, but not pe_mjx (an
    # editable install's finder is not carried over: the .pth lists site-packages only).
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], tmp_path)
    (site,) = (venv / "lib").glob("python3*/site-packages")
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    py = venv / "bin" / "python"
    _run([*pip, "--python", py, "install", "--no-deps", "-q", wheel], tmp_path)

    work = tmp_path / "work"  # outside the checkout: nothing can come from it
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": ""}
    where = _run([py, "-c", "import pe_mjx; print(pe_mjx.__file__)"], work, env=env).stdout
    assert str(venv) in where, where
    cli = str(venv / "bin" / "pe-mjx")
    assert "--pursuers" in _run([cli, "view", "--help"], work, env=env).stdout
    assert _run([cli, "--version"], work, env=env).stdout.strip() == "pe-mjx 0.1.0"
    loaded = _run(
        [py, "-c", "import pe_mjx; print(callable(pe_mjx.load_policy('mix-20-5-8', 'pursuer')))"],
        work,
        env=env,
    )
    assert loaded.stdout.strip() == "True", loaded.stdout
    out = _run(
        [cli, "evaluate", "--pursuers", "mix-20-5-8", "--evaders", "scripted", "--preset",
         "2-1-1", "--backend", "kinematic", "--trials", "2", "--record", "0", "--out", "res"],
        work,
        env=env,
    )  # fmt: skip
    # stdout is the report only (no "Failed to import warp" from mujoco's mjx import).
    assert out.stdout.startswith("### Results of 2 pursuers"), out.stdout[:300]
    assert "P_MIX(20,5,8)" in out.stdout and "warp" not in out.stdout + out.stderr
    assert (work / "res" / "results.json").exists()
