"""The paper's twelve co-evolutions (IV-B): four encoders at three scales, 10 million env steps.

Each run trains a pursuer and an evader policy with the same encoder (the paper's P_method and
E_method come from one co-evolution). Run them all, or some, with `python train/launch.py`.
"""

from __future__ import annotations

from pe_mjx.config import ENCODERS
from pe_mjx.ppo.config import TrainConfig

SCALES = ("16-4-4", "20-5-8", "24-6-12")
ENV_STEPS = 10_000_000


def paper_runs(env_steps: int = ENV_STEPS, backend: str = "mjx") -> dict[str, TrainConfig]:
    """Run name ("<encoder>-<preset>") -> its config."""
    return {
        f"{encoder}-{preset}": TrainConfig(
            preset=preset,
            backend=backend,
            pursuer_encoder=encoder,
            evader_encoder=encoder,
            env_steps=env_steps,
        )
        for preset in SCALES
        for encoder in ENCODERS
    }
