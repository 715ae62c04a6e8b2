"""The tiny co-evolution config shared by the trainer and checkpoint tests.

One definition, so both test modules compile the same program (the persistent compile cache that
`make test` enables then serves the second one).
"""

from __future__ import annotations

from typing import Any

from pe_mjx.experiment import ExperimentConfig, default_config

TINY: dict[str, Any] = {
    "backend": "kinematic",
    "ppo.num_envs": 8,
    "ppo.unroll_length": 8,
    "ppo.update_epochs": 1,
    "ppo.num_minibatches": 2,
    "eval_every": 0,
    "checkpoint_every": 2,
    "pursuer.network.width": 16,
    "pursuer.network.hidden": 32,
    "evader.network.width": 16,
    "evader.network.hidden": 32,
}


def tiny(preset: str = "4-1-2", **changes: Any) -> ExperimentConfig:
    """TINY in `preset` with a 4-iteration budget, plus `changes` (dotted paths as keywords:
    `tiny(**{"evader.policy": "scripted"})`)."""
    return default_config(preset).override({**TINY, "env_steps": 8 * 8 * 4, **changes})
