"""`TrainConfig`: every hyperparameter of a co-evolution run (the `pe-mjx train` flags).

Kept free of JAX/flax imports so that the CLI can build its flags cheaply.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from pe_mjx.config import ENCODERS, TEAMS, EnvConfig, get_preset

if TYPE_CHECKING:
    from pe_mjx.networks import NetworkConfig


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """Co-evolution of a pursuer and an evader policy (every field is a `pe-mjx train` flag)."""

    preset: str = "20-5-8"
    """Scenario preset (P-E-K) to train in."""
    backend: str = "mjx"
    """Env backend: "mjx" (MuJoCo MJX physics) or "kinematic" (exact unicycle arcs, faster)."""
    pursuer: str = "learn"
    """Pursuer team: "learn", "scripted", "random", or a run directory to play frozen."""
    evader: str = "learn"
    """Evader team: "learn", "scripted", "random", or a run directory to play frozen."""
    pursuer_encoder: str = "mix"
    """Pursuer state encoder: mix, mean, birnn or mlp."""
    evader_encoder: str = "mix"
    """Evader state encoder: mix, mean, birnn or mlp."""
    width: int = 32
    """Encoder embedding width."""
    num_heads: int = 4
    """Attention heads (mix)."""
    hidden: int = 64
    """Policy/value head width."""
    nearest_k: int | None = None
    """Keep only the k nearest entities of each type (None keeps all, as the paper does)."""
    mix_queries: str = "own"
    """MIX attention queries: "own" (the agent's own token attends to every entity; ~6x cheaper)
    or "all" (full self-attention over all tokens, then pooled)."""
    env_steps: int = 10_000_000
    """Training budget in env steps (one control step of one arena)."""
    num_envs: int = 64
    """Arenas stepped in parallel."""
    unroll_length: int = 32
    """Control steps per arena per iteration."""
    update_epochs: int = 2
    """PPO passes over each iteration's data."""
    num_minibatches: int = 4
    """Minibatches per PPO pass."""
    learning_rate: float = 3e-4
    lr_schedule: str = "linear"
    """"linear" (decay to 0 over the budget) or "constant"."""
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_epsilon: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.01
    max_grad_norm: float = 0.5
    pursuer_reward_scale: float = 0.01
    """Pursuer rewards are multiplied by this before GAE (its shaping term is ~10/step)."""
    evader_reward_scale: float = 0.1
    """Evader rewards are multiplied by this before GAE."""
    seed: int = 0
    eval_every: int = 20
    """Evaluate against the scripted opponents every this many iterations (0: never)."""
    eval_envs: int = 16
    """Arenas per evaluation (each runs one full episode)."""
    checkpoint_every: int = 20
    """Save a checkpoint every this many iterations (and at the end)."""

    def __post_init__(self) -> None:
        get_preset(self.preset)
        for team in TEAMS:
            encoder = getattr(self, f"{team}_encoder")
            if encoder not in ENCODERS:
                raise ValueError(
                    f"invalid config: {team}_encoder must be one of {ENCODERS}, got {encoder!r}"
                )
            mode = getattr(self, team)
            if not mode:
                raise ValueError(f"invalid config: {team} must be learn, scripted, random or a run")
        if self.pursuer != "learn" and self.evader != "learn":
            raise ValueError("invalid config: pursuer and evader are both fixed; nothing to learn")
        positive = ("env_steps", "num_envs", "unroll_length", "update_epochs", "num_minibatches")
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"invalid config: {name} must be >= 1, got {getattr(self, name)}")
        if self.lr_schedule not in ("linear", "constant"):
            raise ValueError("invalid config: lr_schedule must be linear or constant")
        if self.backend not in ("mjx", "kinematic"):
            raise ValueError("invalid config: backend must be mjx or kinematic")

    @property
    def steps_per_iteration(self) -> int:
        return self.num_envs * self.unroll_length

    @property
    def num_iterations(self) -> int:
        return -(-self.env_steps // self.steps_per_iteration)

    def env_config(self) -> EnvConfig:
        return get_preset(self.preset)

    def network_config(self, team: str, env_config: EnvConfig) -> NetworkConfig:
        from pe_mjx.networks import NetworkConfig

        own = env_config.team(team).num_agents
        other = env_config.team("evader" if team == "pursuer" else "pursuer").num_agents
        encoder = getattr(self, f"{team}_encoder")
        counts = (own - 1, other, env_config.arena.num_obstacles) if encoder == "mlp" else None
        return NetworkConfig(
            encoder=encoder,
            width=self.width,
            num_heads=self.num_heads,
            hidden=self.hidden,
            nearest_k=self.nearest_k,
            mlp_counts=counts,
            mix_queries=self.mix_queries,
        )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"invalid train config: unknown fields {sorted(unknown)}")
        return cls(**d)
