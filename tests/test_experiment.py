"""pe_mjx/experiment.py: the experiment tree's checks name the field, and its configs round-trip
through JSON."""

from __future__ import annotations

import json

import pytest

from pe_mjx.experiment import NetworkConfig, default_config


def test_experiment_validation_names_the_field():
    base = default_config("4-1-2")
    with pytest.raises(ValueError, match=r"pursuer\.network\.encoder"):
        base.override({"pursuer.network.encoder": "transformer"})
    with pytest.raises(ValueError, match="num_envs"):
        base.override({"ppo.num_envs": 0})
    with pytest.raises(ValueError, match="both fixed"):
        base.override({"pursuer.policy": "scripted", "evader.policy": "random"})
    with pytest.raises(ValueError, match="unknown preset"):
        default_config("3-3-3")


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"encoder": "transformer"}, "encoder"),
        ({"width": 0}, "width"),
        ({"width": 32, "num_heads": 3}, "num_heads"),
        ({"num_heads": 0}, "num_heads"),
        ({"hidden": 0}, "hidden"),
        ({"nearest_k": 0}, "nearest_k"),
        ({"length_unit": 0.0}, "length_unit"),
        ({"length_unit": float("nan")}, "length_unit"),
        ({"length_unit": float("inf")}, "length_unit"),
        ({"encoder": "mlp", "mlp_counts": (1, 2)}, "mlp_counts"),
        ({"mlp_counts": (1, -2, 3)}, "mlp_counts"),
        ({"mix_queries": "some"}, "mix_queries"),
    ],
)
def test_network_validation_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        NetworkConfig(**kwargs)


def test_network_config_round_trip():
    for cfg in [
        NetworkConfig(),
        NetworkConfig(encoder="mlp", mlp_counts=(19, 5, 8), nearest_k=4, width=16, num_heads=2),
        NetworkConfig(encoder="birnn", hidden=32, mix_queries="all"),
    ]:
        again = NetworkConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
        assert again == cfg
    with pytest.raises(ValueError, match="unknown"):
        NetworkConfig.from_dict({"encoder": "mix", "depth": 3})
    with pytest.raises(ValueError, match="width"):
        NetworkConfig.from_dict({"width": -1})
