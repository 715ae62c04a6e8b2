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


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("dup.yaml", "ppo:\n  num_envs: 8\nppo:\n  gamma: 0.5\n"),
        ("dup.json", '{"ppo": {"num_envs": 8}, "ppo": {"gamma": 0.5}}'),
        ("nested.yaml", "ppo:\n  gamma: 0.5\n  gamma: 0.9\n"),
    ],
)
def test_a_key_given_twice_is_refused_not_dropped(tmp_path, name, text):
    """json and PyYAML keep the last of two keys: the first `ppo` block (num_envs 8) was
    dropped without a word."""
    from pe_mjx.experiment import read_config_file

    (tmp_path / name).write_text(text)
    with pytest.raises(ValueError, match=r"not valid JSON/YAML: key '(ppo|gamma)' appears twice"):
        read_config_file(tmp_path / name)


def test_yaml_reads_an_exponent_without_a_dot_as_a_number_and_merges_still_override(tmp_path):
    """YAML 1.1 (PyYAML) read `1e-4` as the string "1e-4": a refused learning rate."""
    from pe_mjx.experiment import read_config_file

    path = tmp_path / "c.yaml"
    path.write_text("ppo:\n  learning_rate: 1e-4\n  entropy_coef: 5E-3\n")
    config = read_config_file(path)
    assert (config.ppo.learning_rate, config.ppo.entropy_coef) == (1e-4, 5e-3)
    path.write_text(
        "pursuer:\n  network: &net {width: 32, encoder: mean}\n"
        "evader:\n  network:\n    <<: *net\n    width: 16\n"
    )
    evader = read_config_file(path).evader.network  # a merge key, then an override: no twice
    assert (evader.encoder, evader.width) == ("mean", 16)
