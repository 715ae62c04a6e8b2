"""Config validation, presets and (de)serialisation (SPEC 2.1, 6)."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from pe_mjx.config import (
    PRESETS,
    ArenaConfig,
    EnvConfig,
    RewardConfig,
    TeamConfig,
    from_dict,
    get_preset,
)
from pe_mjx.experiment import PoolConfig


def test_presets_cover_paper_small_and_large():
    for name in ("16-4-4", "20-5-8", "24-6-12", "2-1-1", "4-1-2"):
        assert name in PRESETS
    for name, cfg in PRESETS.items():
        assert cfg.name == name
        p, e, k = (int(x) for x in name.split("-"))
        assert (cfg.pursuer.num_agents, cfg.evader.num_agents, cfg.arena.num_obstacles) == (p, e, k)
    assert max(c.num_agents + c.arena.num_obstacles for c in PRESETS.values()) >= 420


def test_paper_table_one_defaults():
    cfg = get_preset("20-5-8")
    assert cfg.control_dt == pytest.approx(0.2)
    assert cfg.max_steps == 1000
    assert cfg.arena.radius == 5.0
    assert (cfg.arena.obstacle_radius_min, cfg.arena.obstacle_radius_max) == (0.3, 0.5)
    p, e = cfg.pursuer, cfg.evader
    assert (p.radius, p.max_speed, p.max_turn_rate) == (0.1, 0.2, pytest.approx(math.pi / 3))
    assert (p.num_speeds, p.num_turn_rates, p.num_actions) == (3, 13, 39)
    assert (e.radius, e.max_speed, e.max_turn_rate) == (0.15, 0.4, pytest.approx(math.pi / 2))
    assert (e.num_speeds, e.num_turn_rates, e.num_actions) == (5, 19, 95)
    assert cfg.capture_eps == pytest.approx(0.25)
    assert cfg.num_substeps == 1


def test_large_preset_has_paper_density():
    big, paper = get_preset("240-60-120"), get_preset("24-6-12")
    density = [(c.num_agents + c.arena.num_obstacles) / c.arena.radius**2 for c in (big, paper)]
    assert density[0] == pytest.approx(density[1])


def test_unknown_preset_lists_known():
    with pytest.raises(ValueError, match=r"unknown preset 'nope'.*16-4-4"):
        get_preset("nope")


def _team(**kw):
    base = dict(
        num_agents=2, radius=0.1, max_speed=0.2, max_turn_rate=1.0, num_speeds=3, num_turn_rates=5
    )
    base.update(kw)
    return TeamConfig(**base)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("radius", -0.1),
        ("radius", 0.0),
        ("num_agents", 0),
        ("max_speed", 0.0),
        ("max_turn_rate", -1.0),
        ("num_speeds", 1),
        ("num_turn_rates", 0),
        ("min_turning_radius", -0.5),
    ],
)
def test_bad_team_field_named(field, value):
    with pytest.raises(ValueError, match=field):
        _team(**{field: value})


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"radius": -1.0}, "arena.radius"),
        ({"num_obstacles": -1}, "arena.num_obstacles"),
        ({"obstacle_radius_min": 0.6}, "arena.obstacle_radius_min"),
        ({"obstacle_radius_min": 0.0}, "arena.obstacle_radius_min"),
        ({"spawn_clearance": -0.1}, "arena.spawn_clearance"),
        ({"spawn_candidates": 0}, "arena.spawn_candidates"),
    ],
)
def test_bad_arena_field_named(kw, field):
    with pytest.raises(ValueError, match=field):
        ArenaConfig(**kw)


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"collision": 1.0}, "reward.collision"),
        ({"danger_distance": 0.0}, "reward.danger_distance"),
        ({"capture_distance": -1.0}, "reward.capture_distance"),
        ({"pursuit_nearest": 0}, "reward.pursuit_nearest"),
    ],
)
def test_bad_reward_field_named(kw, field):
    with pytest.raises(ValueError, match=field):
        RewardConfig(**kw)


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"control_dt": 0.0}, "control_dt"),
        ({"physics_dt": 0.03}, "physics_dt"),
        ({"physics_dt": 0.5}, "physics_dt"),
        ({"max_steps": 0}, "max_steps"),
        ({"capture_radius": -0.1}, "capture_radius"),
        ({"mask_horizon": -0.2}, "mask_horizon"),
        ({"mask_points": 0}, "mask_points"),
    ],
)
def test_bad_env_field_named(kw, field):
    with pytest.raises(ValueError, match=field):
        get_preset("2-1-1").replace(**kw)


def test_a_saved_config_with_a_retired_field_still_loads():
    """Runs saved before `actuator_time_constant` went (shipped policies among them) load, and
    the field is gone from what is written now."""
    saved = {**get_preset("2-1-1").to_dict(), "actuator_time_constant": 0.005}
    config = EnvConfig.from_dict(saved)
    assert config == get_preset("2-1-1")
    assert "actuator_time_constant" not in config.to_dict()
    with pytest.raises(ValueError, match="unknown fields"):
        EnvConfig.from_dict({**saved, "actuator_time_constan": 0.005})


def test_too_many_obstacles_names_arena_fields():
    cfg = get_preset("2-1-1")
    with pytest.raises(ValueError, match=r"arena\.radius.*arena\.num_obstacles") as err:
        cfg.with_counts(2, 1, 40)
    assert "cannot be placed" in str(err.value)
    with pytest.raises(ValueError, match=r"arena\.radius"):
        cfg.with_counts(200, 1, 1)


def test_arena_too_small_for_entities():
    with pytest.raises(ValueError, match=r"arena\.radius"):
        EnvConfig(arena=ArenaConfig(radius=0.6, num_obstacles=0))


def test_with_counts_and_replace():
    cfg = get_preset("20-5-8").with_counts(3, 2, 1)
    assert cfg.name == "3-2-1"
    assert (cfg.pursuer.num_agents, cfg.evader.num_agents, cfg.arena.num_obstacles) == (3, 2, 1)
    assert cfg.arena.radius == 5.0 and cfg.pursuer.radius == 0.1
    assert cfg.replace(capture_radius=0.5).capture_eps == 0.5
    assert cfg.team("evader") is cfg.evader
    with pytest.raises(ValueError, match="unknown team"):
        cfg.team("referee")


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_json_round_trip(name):
    cfg = PRESETS[name]
    back = EnvConfig.from_dict(json.loads(cfg.to_json()))
    assert back == cfg


def test_from_dict_rejects_bad_input():
    d = get_preset("2-1-1").to_dict()
    with pytest.raises(ValueError, match="unknown fields"):
        EnvConfig.from_dict({**d, "speed": 3})
    with pytest.raises(ValueError, match="arena"):
        EnvConfig.from_dict({**d, "arena": {**d["arena"], "walls": 1}})
    with pytest.raises(ValueError, match="pursuer"):
        EnvConfig.from_dict({**d, "pursuer": 3})
    missing = {k: v for k, v in d["pursuer"].items() if k != "radius"}
    with pytest.raises(ValueError, match="radius"):
        EnvConfig.from_dict({**d, "pursuer": missing})
    with pytest.raises(ValueError, match="radius"):
        EnvConfig.from_dict({**d, "pursuer": {**d["pursuer"], "radius": "big"}})
    with pytest.raises(ValueError, match="must be an object"):
        EnvConfig.from_dict([1, 2])
    bad = {**d, "arena": {**d["arena"], "num_obstacles": 99}}
    with pytest.raises(ValueError, match=r"arena\.num_obstacles"):
        EnvConfig.from_dict(bad)


def test_from_dict_reads_a_variadic_tuple_of_any_length():
    """tuple[str, ...] holds any number of items: two were read as (str, Ellipsis) before."""
    fields = {"fixed": [], "p_current": 1.0, "p_fixed": 0.0}
    assert from_dict(PoolConfig, fields).fixed == ()
    for fixed in (["scripted"], ["scripted", "random"], ["a/x", "b/y", "c/z"]):
        pool = from_dict(PoolConfig, {**fields, "fixed": fixed, "p_current": 0.5, "p_fixed": 0.5})
        assert pool.fixed == tuple(fixed)
    with pytest.raises(ValueError, match=r"pool\.fixed"):
        from_dict(PoolConfig, {**fields, "fixed": ["scripted", 3]}, "pool.")


def test_configs_are_frozen():
    cfg = get_preset("2-1-1")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.max_steps = 3  # type: ignore[misc]
