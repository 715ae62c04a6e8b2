"""The tiny co-evolution config shared by the trainer and checkpoint tests.

One definition, so both test modules compile the same program (the persistent compile cache that
`make test` enables then serves the second one).
"""

from __future__ import annotations

from pe_mjx.ppo.config import TrainConfig

TINY = dict(
    preset="4-1-2",
    backend="kinematic",
    num_envs=8,
    unroll_length=8,
    update_epochs=1,
    num_minibatches=2,
    eval_every=0,
    checkpoint_every=2,
    width=16,
    hidden=32,
)


def tiny(**changes) -> TrainConfig:
    """TINY with a 4-iteration budget, plus `changes`."""
    return TrainConfig(**{**TINY, "env_steps": 8 * 8 * 4, **changes})
