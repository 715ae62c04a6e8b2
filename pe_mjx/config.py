"""Frozen keyword-only configs for the game (arena, teams, rewards, env) and the preset registry."""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from typing import Any, ClassVar, Literal, TypeVar

from pe_mjx.names import TEAMS
from pe_mjx.sizes import shorten

T = TypeVar("T")


def _check(cond: bool, field: str, msg: str) -> None:
    if not cond:
        raise ValueError(f"invalid config: {field} {msg}")


def check_finite(obj: Any, prefix: str = "") -> None:
    """Every float field of a config dataclass must be finite (no NaN, no infinity)."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"invalid config: {prefix}{f.name} must be finite, got {value}")


def _scalar_ok(value: Any, kind: Any) -> bool:
    if kind is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if kind is bool:
        return isinstance(value, bool)
    if kind is str:
        return isinstance(value, str)
    if kind is type(None):
        return value is None
    if typing.get_origin(kind) is typing.Literal:
        return value in typing.get_args(kind)
    return False


def _convert(value: Any, kind: Any, where: str) -> Any:
    """`value` (parsed JSON/YAML) as an instance of the annotation `kind`, or ValueError."""
    if dataclasses.is_dataclass(kind):
        return from_dict(kind, value, f"{where}.")
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(kind)
        for option in options:
            if _scalar_ok(value, option):
                return float(value) if option is float else value
        for option in options:
            if typing.get_origin(option) is tuple and isinstance(value, list | tuple):
                return _convert(value, option, where)
    elif origin is tuple:
        args = typing.get_args(kind)
        if isinstance(value, list | tuple):
            variadic = len(args) == 2 and args[1] is Ellipsis  # tuple[X, ...]
            if variadic or len(args) == len(value):
                # tuple[X, ...] of two items is not tuple[X, Ellipsis]
                items = [args[0]] * len(value) if variadic else args
                return tuple(_convert(v, k, where) for v, k in zip(value, items, strict=True))
    elif _scalar_ok(value, kind):
        return float(value) if kind is float else value
    allowed = kind if isinstance(kind, str) else getattr(kind, "__name__", str(kind))
    raise ValueError(
        f"invalid config: {where} has the wrong type or value: {shorten(value)} ({allowed})"
    )


def from_dict(cls: type[T], data: Any, prefix: str = "") -> T:
    """Rebuilds a (nested) frozen config dataclass from `to_dict` output or parsed JSON/YAML.

    Every key must be a field, every field without a default must be given, and every value must
    have its field's type (no strings for numbers, no floats for ints, a Literal's values only);
    the dataclass's own checks then run. Errors are one-line `ValueError`s naming the field path.
    """
    name = prefix.rstrip(".") or cls.__name__
    if not isinstance(data, dict):
        raise ValueError(f"invalid config: {name} must be an object, got {type(data).__name__}")
    retired = getattr(cls, "RETIRED_FIELDS", ())
    data = {k: v for k, v in data.items() if k not in retired}
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(str(k) for k in set(data) - set(fields))  # YAML keys may be numbers
    if unknown:
        raise ValueError(f"invalid config: unknown fields {shorten([prefix + k for k in unknown])}")
    missing = [
        prefix + n
        for n, f in fields.items()
        if n not in data
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ValueError(f"invalid config: missing fields {missing}")
    kwargs = {k: _convert(v, hints[k], prefix + k) for k, v in data.items()}
    return cls(**kwargs)


def to_dict(config: Any) -> dict[str, Any]:
    """A config dataclass as plain JSON-ready data (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def merge(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """`base` with `changes` applied recursively (a partial config over a full one)."""
    out = dict(base)
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


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
    min_agents: int | None = None
    """Draw the team's size per episode, uniformly in [min_agents, num_agents] (None: always
    num_agents). The others are absent for the episode (`names.ABSENT`): parked outside the
    arena, they never move, collide, earn reward or count in an outcome, and no one observes them
    (their mask entries are False); arrays keep the num_agents shapes."""

    def __post_init__(self) -> None:
        check_finite(self)
        _check(self.num_agents >= 1, "num_agents", f"must be >= 1, got {self.num_agents}")
        _check(
            self.min_agents is None or 1 <= self.min_agents <= self.num_agents,
            "min_agents",
            f"must be in 1..num_agents ({self.num_agents}) or None, got {self.min_agents}",
        )
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
    """Smallest obstacle radius in metres (each reset draws radii uniformly in [min, max])."""
    obstacle_radius_max: float = 0.5
    """Largest obstacle radius in metres."""
    spawn_clearance: float = 0.15
    """Minimum gap between any two things (and to the wall) at spawn, in metres."""
    spawn_candidates: int = 64
    """Candidate positions drawn per entity by the placement sampler (first valid one wins)."""
    min_obstacles: int | None = None
    """Draw the obstacle count per episode, uniformly in [min_obstacles, num_obstacles] (None:
    always num_obstacles); the others are absent (radius 0, outside the arena, masked out of
    every observation)."""

    def __post_init__(self) -> None:
        check_finite(self)
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
        _check(
            self.min_obstacles is None or 0 <= self.min_obstacles <= self.num_obstacles,
            "arena.min_obstacles",
            f"must be in 0..num_obstacles ({self.num_obstacles}) or None, got {self.min_obstacles}",
        )


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
    pursuit_nearest: int | None = None
    """Sum f_p's shaping over each pursuer's k nearest active evaders only (ours; None: over every
    evader, as the paper). In a large arena the paper's sum is dominated by evaders far out of a
    local policy's view: at a 240-60-120 reset it is 63 per pursuer and step, 17 of it from the
    4 nearest evaders (at 20-5-8: 16.6 in all; experiments/results/pursuit_shaping.py), so a
    pursuer's return is mostly what it can neither see nor change; set it to the network's
    `nearest_k` there."""
    capture: float = 5000.0
    """r_s: reward to each pursuer that captures an evader this step. It must beat shadowing the
    evader at d_cap for the rest of the discounted horizon, f_p,max / (1 - gamma) = 40 / 0.01 =
    4000 at gamma 0.99; with r_s = 50 the pursuers learned to follow, not to capture."""
    evader_alive: float = 1.0
    """r_e: per-step reward of an evader that is still active."""
    evader_flee: float = 0.0
    """Weight, per metre, of the evaders' potential-based flee shaping (ours, not in the paper):
    each step an evader gains evader_flee times the change of its distance to the nearest
    pursuer, capped at flee_range. 0 disables it."""
    flee_range: float = 2.0
    """Distance in metres beyond which the flee shaping's potential stops growing."""
    opponent_danger_distance: float | None = None
    """d_danger of the evader's f_c terms to pursuers, in metres (None: danger_distance). The
    paper uses one d_danger for every f_c; a larger one here gives evaders a dense signal to
    keep away from pursuers (docs/results.md, evader diagnosis)."""

    def __post_init__(self) -> None:
        check_finite(self)
        _check(self.collision <= 0, "reward.collision", "(r_c) must be <= 0")
        _check(self.danger_distance > 0, "reward.danger_distance", "must be > 0")
        _check(self.capture_distance > 0, "reward.capture_distance", "must be > 0")
        _check(
            self.pursuit_nearest is None or self.pursuit_nearest >= 1,
            "reward.pursuit_nearest",
            "must be >= 1 or None",
        )
        _check(self.evader_flee >= 0, "reward.evader_flee", "must be >= 0")
        _check(self.flee_range > 0, "reward.flee_range", "must be > 0")
        _check(
            self.opponent_danger_distance is None or self.opponent_danger_distance > 0,
            "reward.opponent_danger_distance",
            "must be > 0 or None",
        )


@dataclasses.dataclass(frozen=True, kw_only=True)
class EnvConfig:
    """Everything that defines one game; every constant of the rules lives here."""

    name: str = "custom"
    """The game's label: its preset's name (P-E-K) or "custom"; used in run names, titles and
    the MJCF model name, never by the rules."""
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
    physics_dt: float = 0.2
    """MJX physics step in seconds; control_dt must be a whole multiple of it. Every physics step
    ends exactly on the commanded arc (deadbeat actuators, chord commands), so substeps add no
    accuracy, only cost (docs/design.md, "MJX actuation")."""
    max_steps: int = 1000
    """Episode limit in control steps (truncation)."""
    capture_radius: float | None = None
    """epsilon in metres; None means contact, r_pursuer + r_evader."""
    mask_horizon: float = 0.2
    """Look-ahead of the action mask in seconds."""
    mask_points: int = 4
    """Points checked along each action's arc within the look-ahead."""
    RETIRED_FIELDS: ClassVar[tuple[str, ...]] = ("actuator_time_constant",)
    """Fields of older configs that are read and dropped: `actuator_time_constant` went when the
    MJX velocity actuators became deadbeat (a lag let agents coast past the arc that the action
    mask checked; docs/design.md), so saved runs and shipped policies still load."""

    def __post_init__(self) -> None:
        check_finite(self)
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
        return to_dict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EnvConfig:
        """Rebuild from `to_dict` output; unknown or missing keys raise ValueError."""
        return from_dict(cls, d)


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


def _ackermann_pursuers(config: EnvConfig, min_turning_radius: float) -> EnvConfig:
    """`config` with Ackermann pursuers: actions turning tighter than the radius are masked."""
    pursuer = dataclasses.replace(config.pursuer, min_turning_radius=min_turning_radius)
    return config.replace(pursuer=pursuer)


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
    # The paper's physical setup (section V): 4 Ackermann pursuers chase 2 evaders in an indoor
    # arena of about 3 m radius. The paper gives neither the obstacle count nor the minimum
    # turning radius: 2 obstacles, and 0.4 m, typical of small Ackermann robots.
    "4-2-2": _ackermann_pursuers(_paper(4, 2, 2, arena_radius=3.0), min_turning_radius=0.4),
}
PRESETS = {name: cfg.replace(name=name) for name, cfg in PRESETS.items()}
PresetName = Literal[tuple(PRESETS)]  # type: ignore[valid-type]
"""A preset's name, as a type (the command line lists the choices)."""


def get_preset(name: str) -> EnvConfig:
    """Looks up a named preset; unknown names raise ValueError listing the known ones."""
    if isinstance(name, str) and name in PRESETS:  # a list was "unhashable type"
        return PRESETS[name]
    raise ValueError(f"unknown preset {name!r}; known presets: {', '.join(PRESETS)}")


def scene_by_counts(name: str) -> EnvConfig:
    """A preset by its name, or the scene "P-E-K" (pursuers, evaders, obstacles) under 24-6-12's
    rules at its density: the arena's area grows with the entity count, the 240-60-120 preset's
    rule (the scenes beyond the paper's in docs/results.md)."""
    if name in PRESETS:
        return PRESETS[name]
    p, e, k = (int(x) for x in name.split("-"))
    base = PRESETS["24-6-12"]
    radius = 5.0 * math.sqrt((p + e + k) / 42)
    return base.replace(
        name=name,
        pursuer=dataclasses.replace(base.pursuer, num_agents=p),
        evader=dataclasses.replace(base.evader, num_agents=e),
        arena=dataclasses.replace(base.arena, radius=radius, num_obstacles=k),
    )
