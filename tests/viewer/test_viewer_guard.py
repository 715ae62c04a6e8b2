"""The viewer's input checks without a server: GUI value rules and where policy paths may point."""

from __future__ import annotations

import dataclasses
import math

import pytest

from pe_mjx.config import get_preset
from pe_mjx.viewer.guard import GuiValueError, PolicyAccess, Rule, check_value
from pe_mjx.viewer.live import PolicyError, load_team_policy


@dataclasses.dataclass
class Handle:
    """The few properties of a viser handle that the rules read."""

    label: str = "x"
    min: float | None = None
    max: float | None = None
    options: tuple[str, ...] = ()


NUMBER = Handle(min=0, max=64)


@pytest.mark.parametrize(
    ("handle", "rule", "value", "expected"),
    [
        (NUMBER, Rule("int"), 3, 3),
        (NUMBER, Rule("int"), 3.0, 3),
        (NUMBER, Rule("float"), 2, 2.0),
        (Handle(), Rule("int", minimum=0, maximum=9), 9, 9),
        (Handle(options=("a", "b")), Rule("choice"), "b", "b"),
        (Handle(), Rule("bool"), False, False),
        (Handle(), Rule("button"), True, True),
        (Handle(), Rule("text"), "runs/mix-2-1-1", "runs/mix-2-1-1"),
    ],
)
def test_valid_values_pass_with_the_handles_type(handle, rule, value, expected):
    out = check_value(handle, rule, value)
    assert out == expected and type(out) is type(expected)


@pytest.mark.parametrize(
    ("handle", "rule", "value", "message"),
    [
        (NUMBER, Rule("int"), 65, r"must be in \[0, 64\]"),
        (NUMBER, Rule("int"), -1, r"must be in \[0, 64\]"),
        (NUMBER, Rule("int"), 1e30, "must be in"),
        (NUMBER, Rule("int"), 2.5, "whole number"),
        (NUMBER, Rule("float"), math.nan, "finite"),
        (NUMBER, Rule("float"), math.inf, "finite"),
        (NUMBER, Rule("int"), True, "expected a number"),
        (NUMBER, Rule("int"), "3", "expected a number"),
        (NUMBER, Rule("int"), None, "expected a number"),
        (Handle(), Rule("int", maximum=9), 10, r"must be in \[-inf, 9\]"),
        (Handle(options=("a",)), Rule("choice"), "c", "expected one of a"),
        (Handle(options=("a",)), Rule("choice"), ["a"], "expected one of"),
        (Handle(), Rule("bool"), "false", "true or false"),
        (Handle(), Rule("bool"), 1, "true or false"),
        (Handle(), Rule("button"), False, "not a click"),
        (Handle(), Rule("text"), 5, "expected text"),
        (Handle(), Rule("text"), "a" * 1025, "longer than 1024"),
        (Handle(), Rule("text"), "a\nb", "control characters"),
    ],
)
def test_bad_values_are_refused(handle, rule, value, message):
    with pytest.raises(GuiValueError, match=message):
        check_value(handle, rule, value)


@pytest.fixture
def tree(tmp_path, monkeypatch):
    """cwd/ with runs/a and a symlink out of it; outside/ next to it."""
    cwd, outside = tmp_path / "cwd", tmp_path / "outside"
    (cwd / "runs" / "a").mkdir(parents=True)
    outside.mkdir()
    (cwd / "runs" / "escape").symlink_to(outside)
    monkeypatch.chdir(cwd)
    return cwd, outside


def test_policy_access_allows_run_directories_under_the_roots_only(tree):
    cwd, outside = tree
    access = PolicyAccess.default()
    assert access.allows("runs/a") and access.allows(str(cwd / "runs" / "a"))
    for spec in ("runs/escape", "runs/a/../../../outside", str(outside), "/", "runs/missing"):
        assert not access.allows(spec), spec
    assert PolicyAccess.default([outside]).allows(str(outside))
    assert not PolicyAccess.default([outside]).allows("runs/a")
    assert access.allowing(outside).allows(str(outside))  # a path given on the command line
    assert "the working directory" in access.describe() and str(cwd) not in access.describe()


def test_paths_outside_the_roots_get_one_message_whether_they_exist_or_not(tree):
    _, outside = tree
    config = get_preset("2-1-1")
    access = PolicyAccess.default()
    messages = set()
    for spec in (str(outside), "/no/such/run", "runs/escape"):
        with pytest.raises(PolicyError) as err:
            load_team_policy(spec, config, "pursuer", access=access)
        messages.add(str(err.value).replace(repr(spec), "SPEC"))
    assert len(messages) == 1, messages
    assert "not a run directory under the working directory" in messages.pop()
    # Without `access` (the command line) the path is tried and the error is specific.
    with pytest.raises(PolicyError, match="no such directory"):
        load_team_policy("/no/such/run", config, "pursuer")
