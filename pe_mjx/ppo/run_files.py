"""What a run directory holds beside its checkpoints and logs: config.json (the experiment, what
it resolved to, the code version of every start), and the saved config read back for
`--resume`."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

from pe_mjx.experiment import RESUMABLE, ExperimentConfig
from pe_mjx.policy import store
from pe_mjx.ppo import checkpoint
from pe_mjx.ppo.train import Trainer

CONFIG_FILE = "config.json"


def code_version() -> dict[str, Any]:
    """The package version and, in a git checkout, the commit and whether the tree was dirty."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        out: dict[str, Any] = {"pe_mjx": version("pe-mjx")}
    except PackageNotFoundError:
        out = {"pe_mjx": "unknown"}
    root = Path(__file__).resolve().parents[2]
    if (root / ".git").exists():
        try:
            commit = subprocess.run(
                ["git", "-C", str(root), "rev-parse", "HEAD"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            ).stdout.strip()
            dirty = subprocess.run(
                ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            ).stdout.strip()
            out.update(git_commit=commit, git_dirty=bool(dirty))
        except (OSError, subprocess.SubprocessError):
            pass
    return out


MAX_CONFIG_BYTES = 1 << 20  # an earlier config.json read back for its start history


def _earlier_starts(run_dir: Path) -> list[dict[str, Any]]:
    """The `starts` of the run's existing config.json (none if absent, too large or malformed:
    the history is a record, never a reason to stop a run). A config.json written before
    `starts` existed gives its one code version, as a start whose iteration is not known."""
    path = run_dir / CONFIG_FILE
    try:
        if not path.is_file() or path.stat().st_size > MAX_CONFIG_BYTES:
            return []
        saved = json.loads(path.read_text())
        starts = saved.get("starts")
        if starts is None and isinstance(saved.get("code_version"), dict):
            starts = [{"iteration": None, "code_version": saved["code_version"]}]
    except (OSError, ValueError, AttributeError):
        return []
    if not isinstance(starts, list):
        return []
    known = [s for s in starts if isinstance(s, dict) and "iteration" in s]
    return [s for s in known if s["iteration"] is None or isinstance(s["iteration"], int)]


def write_config(run_dir: Path, trainer: Trainer, start: int) -> None:
    """`config.json`: the whole experiment (rerun it with `pe-mjx train --config`), what it
    resolved to, and the code version; `starts` lists every (re)start of the run with the
    iteration it started from (null: an earlier start not recorded as such) and the code
    version it ran, so a run resumed on newer code keeps the record of the old."""
    version = code_version()
    earlier = _earlier_starts(run_dir) if start else []  # a fresh run starts a new history
    starts = [s for s in earlier if s["iteration"] is None or s["iteration"] < start]
    starts.append({"iteration": start, "code_version": version})
    payload = {
        "experiment": trainer.config.to_dict(),
        "env_config": trainer.env_config.to_dict(),
        "network_configs": {t: c.to_dict() for t, c in trainer.network_configs.items()},
        "code_version": version,
        "starts": starts,
    }
    tmp = run_dir / f"{CONFIG_FILE}.tmp"
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True))
    tmp.replace(run_dir / CONFIG_FILE)


def saved_config(run_dir: str | Path) -> ExperimentConfig:
    """The experiment config saved with a run's latest checkpoint."""
    try:
        return ExperimentConfig.from_dict(checkpoint.read_experiment(run_dir))
    except ValueError as err:
        if isinstance(err, store.CheckpointError):
            raise
        raise store.CheckpointError(f"{run_dir} holds an invalid config: {err}") from None


def resume_config(
    run_dir: str | Path,
    requested: ExperimentConfig | None = None,
    saved: ExperimentConfig | None = None,
) -> ExperimentConfig:
    """The config a resumed run continues with: the saved one, with the `requested` changes to
    the fields in `RESUMABLE` (budget, intervals) applied. Any other change is refused
    (`ValueError` naming each field): it would change the game, the networks or PPO. `saved`:
    the run's saved config when the caller has read it already (`pe-mjx train --resume` reads
    it once, before the parse)."""
    saved = saved_config(run_dir) if saved is None else saved
    if requested is None:
        return saved
    changed = saved.differences(requested)
    refused = [f for f in changed if f not in RESUMABLE]
    if refused:
        raise ValueError(
            f"--resume {run_dir} cannot change {', '.join(refused)}: a resumed run keeps its "
            f"game, networks and PPO settings (only {', '.join(RESUMABLE)} may change); start a "
            f"new run with another --out instead"
        )
    return saved.replace(**{f: getattr(requested, f) for f in changed})
