"""Frozen keyword-only configs for the game (arena, teams, rewards, env) and the preset registry."""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from typing import Any

TEAMS = ("pursuer", "evader")
ENCODERS = ("mix", "mean", "birnn", "mlp")


def _check(cond: bool, field: str, msg: str) -> None:
    if not cond:
        raise ValueError(f"invalid config: {field} {msg}")


def _check_types(cls: type, values: dict[str, Any], prefix: str) -> None:
    """Loaded (JSON) values must have their field's scalar type: no strings for numbers."""
    hints = typing.get_type_hints(cls)
    for name, value in values.items():
        allowed = typing.get_args(hints.get(name)) or (hints.get(name),)
        if value is None and type(None) in allowed:
            continue
        if float in allowed:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        elif int in allowed:
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif str in allowed:
            ok = isinstance(value, str)
        else:
            continue
        _check(ok, f"{prefix}{name}", f"has the wrong type: {value!r}")


@dataclasses.dataclass(frozen=True, kw_only=True)
class TeamConfig:
    """One team of unicycle robots (paper Table I, eq. 2)."""

    num_agents: int
    """Number of robots in the team."""
    radius: float
    """Body radius in metres."""
    max_speed: float
    """v_max in m/s; v is discretised on [0, v_max]."""
    max_turn_rate: float
    """omega_max in rad/s; omega is discretised on [-omega_max, omega_max]."""
    num_speeds: int
    """N_v, number of discrete linear speeds."""
    num_turn_rates: int
    """N_omega, number of discrete turn rates."""
    min_turning_radius: float = 0.0
    """Ackermann constraint (paper V): actions with v/|omega| < this are masked. 0 disables it."""

    def __post_init__(self) -> None:
        _check(self.num_agents >= 1, "num_agents", f"must be >= 1, got {self.num_agents}")
        _check(self.radius > 0, "radius", f"must be > 0, got {self.radius}")
        _check(self.max_speed > 0, "max_speed", f"must be > 0, got {self.max_speed}")
        _check(self.max_turn_rate >= 0, "max_turn_rate", f"must be >= 0, got {self.max_turn_rate}")
        _check(self.num_speeds >= 2, "num_speeds", f"must be >= 2, got {self.num_speeds}")
        _check(
            self.num_turn_rates >= 1, "num_turn_rates", f"must be >= 1, got {self.num_turn_rates}"
        )
        _check(
            self.min_turning_radius >= 0,
            "min_turning_radius",
            f"must be >= 0, got {self.min_turning_radius}",
        )

    @property
    def num_actions(self) -> int:
        return self.num_speeds * self.num_turn_rates


@dataclasses.dataclass(frozen=True, kw_only=True)
class ArenaConfig:
    """The circular arena and its random circular obstacles."""

    radius: float = 5.0
    """R_arena in metres; the wall stands on this circle."""
    num_obstacles: int = 8
    """K, number of obstacles drawn at every reset."""
    obstacle_radius_min: float = 0.3
    obstacle_radius_max: float = 0.5
    spawn_clearance: float = 0.15
    """Minimum gap between any two things (and to the wall) at spawn, in metres."""
    spawn_candidates: int = 64
    """Candidate positions drawn per entity by the placement sampler (first valid one wins)."""

    def __post_init__(self) -> None:
        _check(self.radius > 0, "arena.radius", f"must be > 0, got {self.radius}")
        _check(self.num_obstacles >= 0, "arena.num_obstacles", "must be >= 0")
        _check(
            0 < self.obstacle_radius_min <= self.obstacle_radius_max,
            "arena.obstacle_radius_min/max",
            f"must satisfy 0 < min <= max, got {self.obstacle_radius_min}, "
            f"{self.obstacle_radius_max}",
        )
        _check(self.spawn_clearance >= 0, "arena.spawn_clearance", "must be >= 0")
        _check(self.spawn_candidates >= 1, "arena.spawn_candidates", "must be >= 1")


@dataclasses.dataclass(frozen=True, kw_only=True)
class RewardConfig:
    """Constants of the paper's eqs. (3) and (4); the paper gives no values, these are ours."""

    collision: float = -10.0
    """r_c: reward at contact (gap <= 0); scaled down linearly-ish inside d_danger."""
    danger_distance: float = 0.2
    """d_danger in metres: f_c is negative for gaps below this."""
    pursuit_scale: float = 10.0
    """Numerator of f_p = scale / max(d, d_cap) (10 in the paper)."""
    capture_distance: float = 0.25
    """d_cap in metres: floor of the distance in f_p (caps the shaping term at scale/d_cap)."""
    capture: float = 5000.0
    """r_s: reward to each pursuer that captures an evader this step. It must beat shadowing the
    evader at d_cap for the rest of the discounted horizon, f_p,max / (1 - gamma) = 40 / 0.01 =
    4000 at gamma 0.99; with r_s = 50 the pursuers learned to follow, not to capture."""
    evader_alive: float = 1.0
    """r_e: per-step reward of an evader that is still active."""

    def __post_init__(self) -> None:
        _check(self.collision <= 0, "reward.collision", "(r_c) must be <= 0")
        _check(self.danger_distance > 0, "reward.danger_distance", "must be > 0")
        _check(self.capture_distance > 0, "reward.capture_distance", "must be > 0")


@dataclasses.dataclass(frozen=True, kw_only=True)
class EnvConfig:
    """Everything that defines one game; every constant of the rules lives here."""

    name: str = "custom"
    arena: ArenaConfig = dataclasses.field(default_factory=ArenaConfig)
    pursuer: TeamConfig = dataclasses.field(
        default_factory=lambda: TeamConfig(
            num_agents=20,
            radius=0.1,
            max_speed=0.2,
            max_turn_rate=math.pi / 3,
            num_speeds=3,
            num_turn_rates=13,
        )
    )
    evader: TeamConfig = dataclasses.field(
        default_factory=lambda: TeamConfig(
            num_agents=5,
            radius=0.15,
            max_speed=0.4,
            max_turn_rate=math.pi / 2,
            num_speeds=5,
            num_turn_rates=19,
        )
    )
    reward: RewardConfig = dataclasses.field(default_factory=RewardConfig)
    control_dt: float = 0.2
    """Control step in seconds (one env step)."""
    physics_dt: float = 0.05
    """MJX physics step in seconds; control_dt must be a whole multiple of it."""
    max_steps: int = 1000
    """Episode limit in control steps (truncation)."""
    capture_radius: float | None = None
    """epsilon in metres; None means contact, r_pursuer + r_evader."""
    mask_horizon: float = 0.2
    """Look-ahead of the action mask in seconds."""
    mask_points: int = 4
    """Points checked along each action's arc within the look-ahead."""
    actuator_time_constant: float = 0.005
    """Velocity-actuator lag (mass / kv) of the MJX model, in seconds."""

    def __post_init__(self) -> None:
        _check(self.control_dt > 0, "control_dt", "must be > 0")
        _check(self.physics_dt > 0, "physics_dt", "must be > 0")
        ratio = self.control_dt / self.physics_dt
        _check(
            abs(ratio - round(ratio)) < 1e-6 and round(ratio) >= 1,
            "physics_dt",
            f"must divide control_dt; got control_dt={self.control_dt}, "
            f"physics_dt={self.physics_dt}",
        )
        _check(self.max_steps >= 1, "max_steps", f"must be >= 1, got {self.max_steps}")
        _check(
            self.capture_radius is None or self.capture_radius > 0,
            "capture_radius",
            "must be > 0 or None",
        )
        _check(self.mask_horizon >= 0, "mask_horizon", "must be >= 0")
        _check(self.mask_points >= 1, "mask_points", "must be >= 1")
        _check(self.actuator_time_constant > 0, "actuator_time_constant", "must be > 0")
        self._check_placeable()

    def _check_placeable(self) -> None:
        """Fail fast when the arena cannot hold everything (random placement would fail).

        The bound is conservative: the summed spawn footprints (each radius grown by half the
        clearance) may cover at most 40% of the usable disc, well below random-packing density.
        """
        a = self.arena
        c = a.spawn_clearance
        r_obs = a.obstacle_radius_max + c
        footprint = a.num_obstacles * r_obs**2
        for team in (self.pursuer, self.evader):
            footprint += team.num_agents * (team.radius + c) ** 2
        usable = a.radius - c - max(a.obstacle_radius_max, self.pursuer.radius, self.evader.radius)
        _check(usable > 0, "arena.radius", f"{a.radius} m is too small for the entities' radii")
        fraction = footprint / usable**2
        _check(
            fraction <= 0.4,
            "arena.radius / arena.num_obstacles / pursuer.num_agents / evader.num_agents",
            f"cannot be placed: spawn footprints cover {fraction:.0%} of the arena (at most 40%). "
            f"Use a larger arena.radius or fewer entities.",
        )

    @property
    def num_substeps(self) -> int:
        return round(self.control_dt / self.physics_dt)

    @property
    def num_agents(self) -> int:
        return self.pursuer.num_agents + self.evader.num_agents

    @property
    def capture_eps(self) -> float:
        if self.capture_radius is None:
            return self.pursuer.radius + self.evader.radius
        return self.capture_radius

    def team(self, name: str) -> TeamConfig:
        if name not in TEAMS:
            raise ValueError(f"unknown team {name!r}; expected one of {TEAMS}")
        return getattr(self, name)

    def replace(self, **changes: Any) -> EnvConfig:
        return dataclasses.replace(self, **changes)

    def with_counts(self, pursuers: int, evaders: int, obstacles: int) -> EnvConfig:
        """Same rules with other entity counts (arena unchanged)."""
        return dataclasses.replace(
            self,
            name=f"{pursuers}-{evaders}-{obstacles}",
            pursuer=dataclasses.replace(self.pursuer, num_agents=pursuers),
            evader=dataclasses.replace(self.evader, num_agents=evaders),
            arena=dataclasses.replace(self.arena, num_obstacles=obstacles),
        )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EnvConfig:
        """Rebuild from `to_dict` output; unknown or missing keys raise ValueError."""
        if not isinstance(d, dict):
            raise ValueError(f"env config must be a JSON object, got {type(d).__name__}")
        sub = {"arena": ArenaConfig, "pursuer": TeamConfig, "evader": TeamConfig}
        sub["reward"] = RewardConfig
        kwargs: dict[str, Any] = {}
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"invalid config: unknown fields {sorted(unknown)}")
        for key, value in d.items():
            if key in sub:
                if not isinstance(value, dict):
                    raise ValueError(f"invalid config: {key} must be an object")
                sub_names = {f.name for f in dataclasses.fields(sub[key])}
                bad = set(value) - sub_names
                if bad:
                    raise ValueError(f"invalid config: unknown fields {key}.{sorted(bad)}")
                _check_types(sub[key], value, f"{key}.")
                try:
                    kwargs[key] = sub[key](**value)
                except TypeError as err:  # a missing field
                    raise ValueError(f"invalid config: {key}: {err}") from None
            else:
                kwargs[key] = value
        _check_types(cls, {k: v for k, v in kwargs.items() if k not in sub}, "")
        try:
            return cls(**kwargs)
        except TypeError as err:
            raise ValueError(f"invalid config: {err}") from None


def _paper(pursuers: int, evaders: int, obstacles: int, arena_radius: float = 5.0) -> EnvConfig:
    base = EnvConfig()
    return EnvConfig(
        name=f"{pursuers}-{evaders}-{obstacles}",
        arena=ArenaConfig(radius=arena_radius, num_obstacles=obstacles),
        pursuer=dataclasses.replace(base.pursuer, num_agents=pursuers),
        evader=dataclasses.replace(base.evader, num_agents=evaders),
    )


def _scaled(pursuers: int, evaders: int, obstacles: int, factor: float) -> EnvConfig:
    """The paper's rules with `factor` times the arena area (same entity density as 24-6-12)."""
    return _paper(pursuers, evaders, obstacles, arena_radius=5.0 * math.sqrt(factor))


PRESETS: dict[str, EnvConfig] = {
    # The paper's three scales (Tables II-IV).
    "16-4-4": _paper(16, 4, 4),
    "20-5-8": _paper(20, 5, 8),
    "24-6-12": _paper(24, 6, 12),
    # Small scenes for tests, demos and quick training (smaller arena, similar density).
    "2-1-1": _paper(2, 1, 1, arena_radius=2.0),
    "4-1-2": _paper(4, 1, 2, arena_radius=2.5),
    "8-2-4": _paper(8, 2, 4, arena_radius=3.5),
    # 10x the paper's largest entity count (24+6+12 = 42 -> 420) on 10x the arena area.
    "240-60-120": _scaled(240, 60, 120, 10.0),
}
PRESETS = {name: cfg.replace(name=name) for name, cfg in PRESETS.items()}


def get_preset(name: str) -> EnvConfig:
    """Looks up a named preset; unknown names raise ValueError listing the known ones."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; known presets: {', '.join(PRESETS)}") from None
