"""`EvalConfig`: what one cross-confrontation plays, stated once for `pe-mjx evaluate` and for
`pe_mjx.evaluate.evaluate`.

The config is what decides the results (the scene, the policies, the trials, the seed, the
backend, what is recorded); where they are written, how progress is shown and which earlier
evaluation may be kept are arguments of `pe_mjx.evaluate.run_evaluation`, not fields, so that two
evaluations of equal configs are the same evaluation. `pe-mjx evaluate` embeds this dataclass, so
each of its flags is one field here with its help; checks that the config can state (ranges,
choices, at least one policy a side) are its own (`__post_init__`), and the CLI turns their
`invalid config: <field> ...` into `--<field> ...`. Whether a policy spec names a readable run is
a question for the file system, asked by `pe_mjx.evaluate.check_policy_specs`.

Kept free of JAX imports so that the CLI builds its flags cheaply.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from pe_mjx.config import PRESETS, EnvConfig
from pe_mjx.experiment import Backend
from pe_mjx.names import BACKENDS

SEED_LIMIT = 2**32
"""Seeds are in [0, 2**32) (`jax.random.key` keeps 32 bits; larger ones overflowed)."""
MAX_TRIALS = 100_000
"""Episodes per pairing at most (one vmapped batch: more would exhaust memory)."""
POLICY_KINDS = "scripted, random, a shipped policy or a run"


def _check(cond: bool, field: str, msg: str) -> None:
    if not cond:
        raise ValueError(f"invalid config: {field} {msg}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvalConfig:
    """Every pursuer policy against every evader policy, `trials` episodes each."""

    env: EnvConfig = dataclasses.field(default_factory=lambda: PRESETS["20-5-8"])
    """The scene the trials play, every field a flag as in `pe-mjx train` (--env.pursuer.num-agents
    60 --env.arena.radius 10); its defaults are --preset's (or --config's). Policies trained
    elsewhere play it unchanged: generalization."""
    pursuers: tuple[str, ...] = ("scripted",)
    """Pursuit policies."""
    evaders: tuple[str, ...] = ("scripted",)
    """Evasion policies."""
    trials: int = 100
    """Episodes per pairing (one vmapped batch)."""
    seed: int = 0
    """Seed of the trials: trial i of every pairing starts from the same arena."""
    backend: Backend = "mjx"
    """Env backend: mjx (MuJoCo MJX physics) or kinematic (exact arcs, faster to compile)."""
    record: int = 3
    """Trials per pairing saved as trajectories for `pe-mjx view --replay`."""
    skip_same_method: bool = False
    """Leave out the pairings of two policies with the same encoder, as in the paper's tables (a
    co-evolution's own opponent is never its test opponent)."""

    def __post_init__(self) -> None:
        # tyro and callers may hand lists: the config holds tuples (hashable, frozen).
        object.__setattr__(self, "pursuers", tuple(self.pursuers))
        object.__setattr__(self, "evaders", tuple(self.evaders))
        for team in ("pursuers", "evaders"):
            _check(bool(getattr(self, team)), team, f"needs at least one policy ({POLICY_KINDS})")
        _check(
            1 <= self.trials <= MAX_TRIALS,
            "trials",
            f"must be in 1..{MAX_TRIALS}, got {self.trials}",
        )
        _check(
            self.record >= 0,
            "record",
            f"must be >= 0 (trials saved per pairing), got {self.record}",
        )
        _check(0 <= self.seed < SEED_LIMIT, "seed", f"must be in [0, 2**32), got {self.seed}")
        _check(
            self.backend in BACKENDS,
            "backend",
            f"unknown backend {self.backend!r}; expected {' or '.join(BACKENDS)}",
        )

    @property
    def recorded(self) -> int:
        """Trials per pairing that are actually recorded (no more than are played)."""
        return min(self.record, self.trials)

    def replace(self, **changes: Any) -> EvalConfig:
        return dataclasses.replace(self, **changes)
