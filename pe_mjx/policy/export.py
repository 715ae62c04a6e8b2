"""`pe-mjx export`: a run's team policy as one self-contained StableHLO file (`jax.export`).

The exported function is the greedy policy of `pe_mjx.load_policy(run, team, deterministic=True)`
with the observation normaliser and the parameters folded in as constants; see
`pe_mjx.policy.export_loader` (jax and numpy only) for the file layout and how to run it.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax import export

from pe_mjx.config import EnvConfig
from pe_mjx.names import OBSERVATION_KEYS, other_team
from pe_mjx.networks import greedy_actions
from pe_mjx.policy.export_loader import FORMAT, META, PROGRAM, VERSION
from pe_mjx.policy.inference import dummy_obs, length_scale, network_inputs
from pe_mjx.policy.store import restore_policy_params
from pe_mjx.stages.dynamics import action_table

INPUTS = OBSERVATION_KEYS
# Lowered for both, so that one file runs on a robot computer's CPU or NVIDIA GPU.
PLATFORMS = ("cpu", "cuda")


def export_policy(
    run_dir: str | Path, team: str, config: EnvConfig | None = None
) -> tuple[bytes, dict[str, Any]]:
    """(serialised `jax.export` program, metadata) of one team's greedy policy.

    Args:
      run_dir: a `pe-mjx train` run directory.
      team: "pursuer" or "evader".
      config: the scene whose counts fix the input shapes (default: the run's own scene).
    """
    network, state, net_config, config, _, meta = restore_policy_params(run_dir, team, config)
    num_actions = config.team(team).num_actions
    params = state["params"]
    scale = length_scale(net_config, config)
    if scale is not None:  # baked in: the file plays this scene's counts and arena only
        state = {**state, "length_scale": np.float32(scale)}

    def greedy(*arrays: jax.Array) -> tuple[jax.Array, jax.Array]:
        obs = dict(zip(INPUTS, arrays, strict=True))
        logits, _ = network.apply(params, network_inputs(obs, state))
        return greedy_actions(logits), logits

    obs = dummy_obs(config, team)
    specs = [jax.ShapeDtypeStruct(obs[k].shape, obs[k].dtype) for k in INPUTS]
    exported = export.export(jax.jit(greedy), platforms=PLATFORMS)(*specs)
    v, omega = action_table(config.team(team))
    info = {
        "format": FORMAT,
        "version": VERSION,
        "team": team,
        "inputs": [
            {"name": k, "shape": list(s.shape), "dtype": np.dtype(s.dtype).name}
            for k, s in zip(INPUTS, specs, strict=True)
        ],
        "outputs": [
            {"name": "actions", "shape": [config.team(team).num_agents], "dtype": "int32"},
            {
                "name": "logits",
                "shape": [config.team(team).num_agents, num_actions],
                "dtype": "float32",
            },
        ],
        "action_table": {"v": v.tolist(), "omega": omega.tolist()},
        "counts": {
            f"{team}s": config.team(team).num_agents,
            f"{other_team(team)}s": config.team(other_team(team)).num_agents,
            "obstacles": config.arena.num_obstacles,
        },
        "env_config": config.to_dict(),
        "network_config": net_config.to_dict(),
        "source": {"run": str(run_dir), "step": int(meta["step"])},
        "platforms": list(PLATFORMS),
        "jax_version": jax.__version__,
    }
    return bytes(exported.serialize()), info


def write_policy(path: str | Path, program: bytes, info: dict[str, Any]) -> int:
    """Writes the file atomically (a temporary file renamed); returns its size in bytes."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f, zipfile.ZipFile(f, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(META, json.dumps(info, indent=2, sort_keys=True))
            archive.writestr(PROGRAM, program)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path.stat().st_size
