"""pe_mjx/eval_config.py: an evaluation's config checks itself, one message naming the field."""

from __future__ import annotations

import pytest

from pe_mjx.config import PRESETS
from pe_mjx.eval_config import MAX_TRIALS, EvalConfig


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"trials": 0}, "trials must be in 1..100000, got 0"),
        ({"trials": MAX_TRIALS + 1}, "trials must be in 1.."),
        ({"record": -1}, "record must be >= 0"),
        ({"seed": -1}, r"seed must be in \[0, 2\*\*32\)"),
        ({"seed": 2**32}, r"seed must be in \[0, 2\*\*32\)"),
        ({"backend": "warp"}, "backend unknown backend 'warp'"),
        ({"pursuers": ()}, "pursuers needs at least one policy"),
        ({"evaders": []}, "evaders needs at least one policy"),
    ],
)
def test_a_bad_field_is_one_message_naming_it(changes, message):
    with pytest.raises(ValueError, match=f"invalid config: {message}"):
        EvalConfig(**changes)


def test_policies_are_held_as_tuples_and_recorded_trials_are_at_most_the_played():
    config = EvalConfig(env=PRESETS["2-1-1"], pursuers=["scripted", "random"], trials=2)
    assert config.pursuers == ("scripted", "random")
    assert config.recorded == 2 and config.replace(record=1).recorded == 1
    with pytest.raises(TypeError):
        EvalConfig(PRESETS["2-1-1"])  # keyword-only
