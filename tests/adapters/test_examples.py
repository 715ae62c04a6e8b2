"""The adapter examples, run for real through a subprocess at a tiny budget."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_pettingzoo_rollout_example_plays_episodes():
    script = ROOT / "examples" / "pettingzoo_rollout.py"
    args = ["--preset", "2-1-1", "--episodes", "2", "--seed", "1"]
    result = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stdout.splitlines() if line.startswith("episode ")]
    assert len(lines) == 2, result.stdout
    assert all("pursuer_1" in line and "evader_0" in line for line in lines)
