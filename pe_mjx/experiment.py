"""`ExperimentConfig`: one frozen tree that states a whole training run.

    ExperimentConfig
      env: EnvConfig            the game (arena, teams, rewards, ...), a preset by default
      pursuer / evader: TeamTraining
        policy                  "learn", or a fixed opponent ("scripted", "random", a run
                                directory or a shipped policy name) played frozen
        network: NetworkConfig  that team's actor-critic
        reward_scale            rewards are multiplied by this before GAE
      ppo: PPOConfig            the optimiser and rollout settings
      pool: PoolConfig          one learned team against a pool of opponents (off by
                                default: the paper's plain co-evolution)
      backend, env_steps, seed, eval_*, checkpoint_every   the run

`pe-mjx train` exposes every field as a nested flag (`--env.reward.capture 50`,
`--pursuer.network.encoder mean`, `--ppo.learning-rate 1e-4`) and reads a whole or partial tree
from `--config run.json` / `.yaml`; a preset is the named default of `env`. Every run directory
holds its tree in `config.json`, and `--resume` continues from it, refusing any change but those in
`RESUMABLE` (the budget and the logging intervals).

Kept free of JAX and flax imports so that the CLI builds its flags cheaply.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path, PurePath
from typing import Any, Literal

from pe_mjx.config import PRESETS, EnvConfig, check_finite, from_dict, get_preset, merge, to_dict
from pe_mjx.config_files import read_tree
from pe_mjx.names import BACKENDS, BUILTIN_POLICIES, ENCODERS, TEAMS, other_team

Encoder = Literal["mix", "mean", "birnn", "mlp"]
Backend = Literal["mjx", "kinematic"]
Team = Literal["pursuer", "evader"]
PoolTeam = Literal["pursuer", "evader", "both"]
assert Encoder.__args__ == ENCODERS  # type: ignore[attr-defined]
assert Backend.__args__ == BACKENDS  # type: ignore[attr-defined]
assert Team.__args__ == TEAMS  # type: ignore[attr-defined]

# Fields `--resume` may change: the budget and how often the run logs, evaluates and saves.
RESUMABLE = ("env_steps", "eval_every", "eval_envs", "checkpoint_every")


def _check(cond: bool, field: str, msg: str) -> None:
    if not cond:
        raise ValueError(f"invalid config: {field} {msg}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class NetworkConfig:
    """Actor-critic architecture of one team (SPEC 3.1)."""

    encoder: Encoder = "mix"
    """State encoder: mix (Mix-Attention), mean (Mean-Embedding), birnn or mlp."""
    width: int = 32
    """Embedding width of the encoders (token size, GRU hidden size)."""
    num_heads: int = 4
    """Mix-Attention heads; must divide width."""
    hidden: int = 64
    """Units of each of the two layers of the policy and value heads."""
    nearest_k: int | None = None
    """Keep only the k nearest entities of each type (None: all, as in the paper)."""
    mlp_counts: tuple[int, int, int] | None = None
    """MLP only: the (teammates, opponents, obstacles) counts it was built for; other counts are
    zero-padded or truncated to these. Set by the trainer from the training scene."""
    mix_queries: Literal["own", "all"] = "own"
    """MIX only: "own", the agent's own token attends over all tokens (O(N) per agent); "all",
    full self-attention over all tokens, pooled (O(N^2) per agent, 5-10x slower on CPU)."""
    length_unit: float | None = None
    """Metres per unit of the lengths the network reads about other entities (distances to
    teammates, opponents and obstacles; obstacle radii). None: the arena radius, as in the paper
    (III-B). A fixed unit makes a neighbourhood read the same in any arena of the same density,
    so what a policy learned at one scale applies at another; the agent's own distance from the
    centre stays in arena radii (it places the agent relative to the wall). A policy trained at
    radius R with None plays exactly as before with length_unit = R there."""

    def __post_init__(self) -> None:
        _check(self.encoder in ENCODERS, "encoder", f"must be one of {ENCODERS}")
        _check(self.width >= 1, "width", f"must be >= 1, got {self.width}")
        _check(self.num_heads >= 1, "num_heads", f"must be >= 1, got {self.num_heads}")
        _check(
            self.width % self.num_heads == 0,
            "num_heads",
            f"must divide width={self.width}, got {self.num_heads}",
        )
        _check(self.hidden >= 1, "hidden", f"must be >= 1, got {self.hidden}")
        _check(
            self.nearest_k is None or self.nearest_k >= 1,
            "nearest_k",
            f"must be None or >= 1, got {self.nearest_k}",
        )
        _check(self.mix_queries in ("own", "all"), "mix_queries", "must be own or all")
        _check(
            self.length_unit is None or 0 < self.length_unit < math.inf,
            "length_unit",
            f"must be None or a positive number of metres, got {self.length_unit}",
        )
        if self.mlp_counts is not None:
            counts = tuple(self.mlp_counts)
            _check(
                len(counts) == 3 and all(isinstance(c, int) and c >= 0 for c in counts),
                "mlp_counts",
                f"must be three ints >= 0 (teammates, opponents, obstacles), got {counts!r}",
            )
            object.__setattr__(self, "mlp_counts", counts)

    def for_scene(self, env: EnvConfig, team: str) -> NetworkConfig:
        """This config with `mlp_counts` taken from the scene `env` (MLP only)."""
        if self.encoder != "mlp":
            return dataclasses.replace(self, mlp_counts=None)
        own, other = env.team(team).num_agents, env.team(other_team(team)).num_agents
        counts = (own - 1, other, env.arena.num_obstacles)
        return dataclasses.replace(self, mlp_counts=counts)

    def replace(self, **changes: Any) -> NetworkConfig:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NetworkConfig:
        return from_dict(cls, d)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PPOConfig:
    """Independent PPO, one parameter set per learned team (Brax's PPO building blocks)."""

    num_envs: int = 64
    """Arenas stepped in parallel."""
    unroll_length: int = 32
    """Control steps per arena per iteration."""
    update_epochs: int = 2
    """PPO passes over each iteration's data."""
    num_minibatches: int = 4
    """Minibatches per PPO pass (each must hold at least one arena-step)."""
    learning_rate: float = 1e-3
    """Adam step size (positive) of every learned team without its own learning_rate."""
    lr_schedule: Literal["linear", "constant"] = "linear"
    """linear: decay to 0 over the budget; constant."""
    gamma: float = 0.99
    """Discount, in (0, 1]."""
    gae_lambda: float = 0.95
    """GAE lambda, in (0, 1]."""
    clip_epsilon: float = 0.2
    """PPO ratio clip (positive)."""
    value_coef: float = 0.5
    """Weight of the value loss."""
    entropy_coef: float = 0.01
    """Weight of the entropy bonus."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip (positive)."""

    def __post_init__(self) -> None:
        check_finite(self, "ppo.")
        for name in ("num_envs", "unroll_length", "update_epochs", "num_minibatches"):
            value = getattr(self, name)
            _check(value >= 1, f"ppo.{name}", f"must be >= 1, got {value}")
        samples = self.num_envs * self.unroll_length
        _check(
            self.num_minibatches <= samples,
            "ppo.num_minibatches",
            f"must be <= num_envs * unroll_length = {samples} (a minibatch needs at least one "
            f"arena-step), got {self.num_minibatches}",
        )
        for name in ("learning_rate", "clip_epsilon", "max_grad_norm"):
            _check(
                getattr(self, name) > 0, f"ppo.{name}", f"must be > 0, got {getattr(self, name)}"
            )
        for name in ("gamma", "gae_lambda"):
            value = getattr(self, name)
            _check(0 < value <= 1, f"ppo.{name}", f"must be in (0, 1], got {value}")
        for name in ("value_coef", "entropy_coef"):
            _check(
                getattr(self, name) >= 0, f"ppo.{name}", f"must be >= 0, got {getattr(self, name)}"
            )


@dataclasses.dataclass(frozen=True, kw_only=True)
class TeamTraining:
    """How one team takes part in a run."""

    policy: str = "learn"
    """learn; or a fixed opponent played frozen: scripted, random, a run directory or a shipped
    policy name (assets/policies)."""
    network: NetworkConfig = dataclasses.field(default_factory=NetworkConfig)
    """The team's actor-critic (used when policy is learn)."""
    reward_scale: float = 0.1
    """The team's rewards are multiplied by this before GAE (positive)."""
    learning_rate: float | None = None
    """The team's Adam step size (None: ppo.learning_rate)."""
    init: str | None = None
    """Start the learned team from this policy (a run directory or a shipped policy's name)
    instead of random parameters: its parameters and observation statistics, with a fresh
    optimiser and step-size schedule (fine-tuning, e.g. at another scale). Its network must have
    the parameter shapes of `network` in this scene (MIX, MEAN and BIRNN read any entity
    counts; an MLP only those it was trained with). A resumed run continues from its own
    checkpoint and ignores this."""
    critic_warmup: int = 0
    """For the run's first this many iterations only the team's value head learns (the
    policy head and the encoder the two heads share stay as they are): when fine-tuning in a
    scene where the critic that came with `init` is far off, its advantages would otherwise
    move the actor before the critic has caught up."""

    def __post_init__(self) -> None:
        check_finite(self)
        _check(bool(self.policy), "policy", "must be learn, scripted, random or a run")
        _check(self.critic_warmup >= 0, "critic_warmup", f"must be >= 0, got {self.critic_warmup}")
        _check(
            self.init is None or (bool(self.init) and self.learns),
            "init",
            f"must name a run or shipped policy for a learned team (policy learn); got "
            f"init={self.init!r} with policy={self.policy!r}",
        )
        _check(self.reward_scale > 0, "reward_scale", f"must be > 0, got {self.reward_scale}")
        _check(
            self.learning_rate is None or self.learning_rate > 0,
            "learning_rate",
            f"must be > 0 or None, got {self.learning_rate}",
        )

    @property
    def learns(self) -> bool:
        return self.policy == "learn"


@dataclasses.dataclass(frozen=True, kw_only=True)
class PoolConfig:
    """A learned team trains against a pool of opponents (`pe_mjx.ppo.pool`): the co-evolving
    opponent's current policy, its own past snapshots and fixed policies, each arena's member
    drawn at every reset with these probabilities. With `team="both"` each team faces a
    pool of the other's snapshots with these settings; an arena where both teams drew a
    non-current opponent keeps one of the two (a coin), so that every arena teaches at least one
    team: each team then meets a non-current member with probability q(1 + p)/2, where p is
    `p_current` and q = 1 - p."""

    team: PoolTeam | None = None
    """The learned team that faces the pool, or both (the opponent must learn too); None: no
    pool."""
    snapshot_every: int = 10
    """Snapshot the opponent's parameters every this many iterations (the first at iteration 0)."""
    keep: int = 4
    """Keep the last this many snapshots."""
    fixed: tuple[str, ...] = ()
    """Fixed members, played by the opponent team: builtin policies (scripted, random), shipped
    policies or run directories (resolved when the run starts, as `--<team>.policy` is). The
    metrics name each by its last path part (`member_names`)."""
    p_current: float = 1.0
    """Probability that an arena's opponent is the co-evolving opponent."""
    p_snapshots: float = 0.0
    """Probability of a snapshot (uniform over those kept so far)."""
    p_fixed: float = 0.0
    """Probability of a fixed member (uniform over `fixed`)."""

    def __post_init__(self) -> None:
        check_finite(self, "pool.")
        object.__setattr__(self, "fixed", tuple(self.fixed))
        for name in ("snapshot_every", "keep"):
            value = getattr(self, name)
            _check(value >= 1, f"pool.{name}", f"must be >= 1, got {value}")
        probs = (self.p_current, self.p_snapshots, self.p_fixed)
        _check(
            min(probs) >= 0 and abs(sum(probs) - 1.0) <= 1e-6,
            "pool.p_current / p_snapshots / p_fixed",
            f"must be >= 0 and sum to 1, got {probs}",
        )
        names = self.member_names
        _check(
            all(isinstance(spec, str) and spec.strip() and spec != "learn" for spec in self.fixed)
            and all(name not in ("current", "snapshot", "") for name in names)
            and len(set(names)) == len(names),
            "pool.fixed",
            "must name distinct policies (builtin, shipped or a run directory; not 'learn', "
            f"and no two with one last path part), got {self.fixed}",
        )
        _check(
            bool(self.fixed) == (self.p_fixed > 0),
            "pool.p_fixed",
            f"must be > 0 when pool.fixed names policies and 0 when it is empty, got "
            f"{self.p_fixed} with fixed={self.fixed}",
        )

    @property
    def on(self) -> bool:
        return self.team is not None

    @property
    def member_names(self) -> tuple[str, ...]:
        """Each fixed member's name in the metrics (`pool/vs_<name>/...`): its spec's last path
        part ("mix-20-5-8-10m" for "train/runs/mix-20-5-8-10m")."""
        return tuple(PurePath(str(spec).rstrip("/")).name for spec in self.fixed)

    @property
    def teams(self) -> tuple[str, ...]:
        """The learned teams that face a pool, in `TEAMS` order (none when off)."""
        if self.team is None:
            return ()
        return TEAMS if self.team == "both" else (self.team,)

    @property
    def learned_members(self) -> tuple[tuple[str, str], ...]:
        """(the team that plays it, spec) of each fixed member that is not builtin (a shipped
        policy or a run directory), for each pool: what the caller resolves for the Trainer."""
        return tuple(
            (other_team(team), spec)
            for team in self.teams
            for spec in self.fixed
            if spec not in BUILTIN_POLICIES
        )


@dataclasses.dataclass(frozen=True, kw_only=True)
class ExperimentConfig:
    """A whole co-evolution run (or one team against a fixed opponent); see the module doc."""

    env: EnvConfig = dataclasses.field(default_factory=lambda: training_env("20-5-8"))
    """The game; `--preset` picks its defaults (with the evaders' flee shaping on)."""
    pursuer: TeamTraining = dataclasses.field(
        default_factory=lambda: TeamTraining(reward_scale=0.01)
    )
    """The pursuers (their f_p shaping is ~10 per step and evader, hence the smaller scale)."""
    evader: TeamTraining = dataclasses.field(
        default_factory=lambda: TeamTraining(learning_rate=3e-3)
    )
    """The evaders (a larger step size: at 3e-4 their PPO updates stayed at ~1e-4 KL and they
    did not learn; docs/results.md)."""
    ppo: PPOConfig = dataclasses.field(default_factory=PPOConfig)
    pool: PoolConfig = dataclasses.field(default_factory=PoolConfig)
    """An opponent pool for one learned team (off by default)."""
    backend: Backend = "mjx"
    """Env backend: mjx (MuJoCo MJX physics) or kinematic (exact unicycle arcs, faster)."""
    env_steps: int = 10_000_000
    """Training budget in env steps (one control step of one arena)."""
    seed: int = 0
    """Seed of the parameters, the arenas and the sampled actions (0 <= seed < 2**32)."""
    eval_every: int = 100
    """Evaluate against the scripted opponents every this many iterations (0: never). The
    default keeps the evaluation under 10% of a run's wall time at 20-5-8 for every encoder
    (`tools/bench_eval.py`; a run logs its own share as `perf/eval_share`): 15 points over a
    3M-env-step run of 64 x 32 arenas and steps, 49 over 10M."""
    eval_envs: int = 32
    """Arenas per evaluation (each runs one full episode)."""
    checkpoint_every: int = 20
    """Save a checkpoint every this many iterations (and at the end)."""

    def __post_init__(self) -> None:
        _check(
            self.pursuer.learns or self.evader.learns,
            "pursuer.policy / evader.policy",
            "are both fixed; nothing to learn",
        )
        _check(
            not self.pool.on or (self.pursuer.learns and self.evader.learns),
            "pool.team",
            "needs both teams learning (the pool holds the co-evolving opponent's snapshots)",
        )
        _check(self.env_steps >= 1, "env_steps", f"must be >= 1, got {self.env_steps}")
        _check(0 <= self.seed < 2**32, "seed", f"must be in [0, 2**32), got {self.seed}")
        _check(self.eval_every >= 0, "eval_every", f"must be >= 0, got {self.eval_every}")
        _check(self.eval_envs >= 1, "eval_envs", f"must be >= 1, got {self.eval_envs}")
        _check(
            self.checkpoint_every >= 1,
            "checkpoint_every",
            f"must be >= 1, got {self.checkpoint_every}",
        )

    # ------------------------------------------------------------------ derived

    @property
    def preset(self) -> str:
        """The env's name (the preset it came from, unless renamed)."""
        return self.env.name

    def team(self, name: str) -> TeamTraining:
        _check(name in TEAMS, "team", f"must be one of {TEAMS}, got {name!r}")
        return getattr(self, name)

    @property
    def learned(self) -> tuple[str, ...]:
        return tuple(t for t in TEAMS if self.team(t).learns)

    def network(self, team: str) -> NetworkConfig:
        """The team's network config for this run's scene (MLP counts filled in)."""
        return self.team(team).network.for_scene(self.env, team)

    @property
    def steps_per_iteration(self) -> int:
        return self.ppo.num_envs * self.ppo.unroll_length

    @property
    def num_iterations(self) -> int:
        return -(-self.env_steps // self.steps_per_iteration)

    # ------------------------------------------------------------------ (de)serialisation

    def replace(self, **changes: Any) -> ExperimentConfig:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ExperimentConfig:
        return from_dict(cls, d)

    def override(self, changes: dict[str, Any]) -> ExperimentConfig:
        """This config with fields changed by dotted path, validated as a whole:
        `config.override({"env.reward.capture": 50.0, "ppo.num_envs": 8})`."""
        tree = self.to_dict()
        for path, value in changes.items():
            node = tree
            *parents, leaf = path.split(".")
            for part in parents:
                if not isinstance(node.get(part), dict):
                    raise ValueError(f"invalid config: unknown field {path}")
                node = node[part]
            if leaf not in node:
                raise ValueError(f"invalid config: unknown field {path}")
            node[leaf] = value
        return ExperimentConfig.from_dict(tree)

    def differences(self, other: ExperimentConfig) -> list[str]:
        """Dotted paths of the fields where `other` differs, e.g. ["env.reward.capture"]."""
        return _diff(self.to_dict(), other.to_dict(), "")


def _diff(a: Any, b: Any, prefix: str) -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _diff(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [prefix.rstrip(".")]


def get_path(config: Any, path: str) -> Any:
    """The value at a dotted field path of a config tree (`"env.reward.capture"`)."""
    for part in path.split("."):
        config = getattr(config, part)
    return config


# Training defaults of the game's open constants that the evader diagnosis settled
# (docs/results.md, "Why the evaders did not learn"): the paper's rewards plus the evaders'
# potential-based flee shaping. The presets themselves keep the paper's rewards (flee 0).
EVADER_FLEE = 10.0


def training_env(preset: str) -> EnvConfig:
    """A preset's game with the training-time reward defaults (`EVADER_FLEE`)."""
    env = get_preset(preset)
    return env.replace(reward=dataclasses.replace(env.reward, evader_flee=EVADER_FLEE))


def default_config(preset: str = "20-5-8") -> ExperimentConfig:
    """The default tree for a preset."""
    return ExperimentConfig(env=training_env(preset))


def read_env_file(path: str | Path, preset: str | None = None) -> EnvConfig:
    """A scene from a JSON or YAML file, whole or partial over a preset's (the file's `name`,
    else `preset`, else 20-5-8): an env tree, or an experiment tree or a run's `config.json`,
    whose `env` is taken."""
    path = Path(path)
    data = read_tree(path)
    if isinstance(data.get("env"), dict):
        data = data["env"]
    name = data.get("name")
    base = name if isinstance(name, str) and name in PRESETS else (preset or "20-5-8")
    try:
        return EnvConfig.from_dict(merge(get_preset(base).to_dict(), data))
    except ValueError as err:
        raise ValueError(f"--config {path}: {err}") from None


def read_config_file(path: str | Path, preset: str | None = None) -> ExperimentConfig:
    """An experiment from a JSON or YAML file: a whole tree or a partial one over the preset's
    defaults (the file's `env.name`, else `preset`, else 20-5-8). A run directory's `config.json`
    (which holds the tree under "experiment") is accepted as it is."""
    path = Path(path)
    data = read_tree(path)
    env_name = data.get("env", {}).get("name") if isinstance(data.get("env"), dict) else None
    known = isinstance(env_name, str) and env_name in PRESETS  # a list there is its own error
    base_preset = env_name if known else (preset or "20-5-8")
    try:
        return ExperimentConfig.from_dict(merge(default_config(base_preset).to_dict(), data))
    except ValueError as err:
        raise ValueError(f"--config {path}: {err}") from None
