"""`pe-mjx export` (pe_mjx.policy.export) and its stand-alone loader
(pe_mjx/policy/export_loader.py)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import jax
import numpy as np
import pytest

import pe_mjx
from pe_mjx import cli
from pe_mjx.config import get_preset
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.policy.deploy import Controller
from pe_mjx.policy.export_loader import load
from pe_mjx.policy.ship import ship_policy

ROOT = Path(__file__).resolve().parents[2]
RUN = ROOT / "assets" / "policies" / "mix-20-5-8"
LOADER = ROOT / "pe_mjx" / "policy" / "export_loader.py"
ROBOTS = "4-2-2"
# Exported and live logits: the same XLA program up to fusion and padding (float32 rounding).
LOGIT_TOL = 1e-4
# Modules the loader must run without.
BLOCKED = ("flax", "brax", "optax", "orbax", "pe_mjx", "mujoco", "tyro")


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> Path:
    """The shipped pursuer policy exported for the paper's robot setup, through the CLI."""
    path = tmp_path_factory.mktemp("export") / "pursuer.jaxexport"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        cli.main(["export", str(RUN), "-o", str(path), "--preset", ROBOTS])
    assert f"wrote {path} ({path.stat().st_size:,} bytes): the pursuer policy" in out.getvalue()
    return path


def _observations(arenas: int = 16) -> list[dict[str, np.ndarray]]:
    """Pursuer observations of random 4-2-2 arenas with random velocities (speeds up to 1.2 times
    the evaders' maximum): a list of one-arena observation dicts."""
    env = PursuitEvasionEnv(get_preset(ROBOTS), backend="kinematic")

    @jax.jit
    @jax.vmap
    def observe(rng):
        state = env.reset(rng)
        vel = jax.random.uniform(jax.random.fold_in(rng, 1), (env.num_agents, 2), minval=-0.34)
        return env.observe(state.world.replace(vel=vel * 1.4))["pursuer"]

    obs = jax.device_get(observe(jax.random.split(jax.random.key(7), arenas)))
    return [{k: v[b] for k, v in obs.items()} for b in range(arenas)]


def _smaller(obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A 3-pursuer, 1-evader, 1-obstacle observation (rows and entities dropped), which the
    loader pads to the exported 4-2-2 shapes."""
    entities = {"teammates": 2, "opponents": 1, "obstacles": 1}
    entities.update({k.removesuffix("s") + "_mask": n for k, n in entities.items()})
    return {k: v[:3, : entities[k]] if k in entities else v[:3] for k, v in obs.items()}


def test_exported_policy_equals_live_policy(exported, tmp_path):
    """On the same observations (the exported scene's, and a smaller scene's that the loader
    pads), the file gives the live greedy policy's actions and logits, and so does the loader
    in a subprocess where flax, brax, the training code and pe_mjx cannot be imported."""
    live = pe_mjx.load_policy(RUN, team="pursuer", deterministic=True)
    network_logits = jax.jit(_live_logits(RUN))
    policy = load(exported)
    assert policy.team == "pursuer" and policy.num_agents == 4 and policy.num_actions == 39
    full = _observations()
    cases = full + [_smaller(c) for c in full[:4]]
    assert cases[-1]["obstacles"].shape == (3, 1, 4) and cases[-1]["teammate_mask"].shape == (3, 2)
    np.savez(
        tmp_path / "obs.npz", **{f"{i}/{k}": v for i, c in enumerate(cases) for k, v in c.items()}
    )

    want_actions = [np.asarray(live(c, jax.random.key(0))) for c in cases]
    want_logits = [np.asarray(network_logits(c)) for c in cases]
    for c, actions, logits in zip(cases, want_actions, want_logits, strict=True):
        got_actions, got_logits = policy.apply(c)
        np.testing.assert_array_equal(got_actions, actions)
        np.testing.assert_allclose(got_logits, logits, rtol=0, atol=LOGIT_TOL)

    script = tmp_path / "run_loader.py"
    script.write_text(_LOADER_SCRIPT.format(blocked=BLOCKED, loader=str(LOADER)))
    result = subprocess.run(
        [sys.executable, str(script), str(exported), str(tmp_path / "obs.npz"), str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "blocked: flax" in result.stdout  # the blocker works
    out = np.load(tmp_path / "out.npz")
    for i, (actions, logits) in enumerate(zip(want_actions, want_logits, strict=True)):
        np.testing.assert_array_equal(out[f"{i}/actions"], actions)
        np.testing.assert_allclose(out[f"{i}/logits"], logits, rtol=0, atol=LOGIT_TOL)


def test_a_length_unit_is_exported_for_the_scene_it_fixes(tmp_path):
    """The shipped pursuers reading neighbour lengths in units of 5 m (`pe-mjx ship
    --length-unit 5`), exported for 4-2-2 (a 3 m arena): the file acts as the live policy
    resolved for that scene, not as the same parameters reading arena radii."""
    metric = ship_policy(RUN, "m5", dest=tmp_path, length_unit=5.0)[0]
    path = tmp_path / "m5.jaxexport"
    with contextlib.redirect_stdout(io.StringIO()):
        cli.main(["export", str(metric), "-o", str(path), "--preset", ROBOTS])
    scene = get_preset(ROBOTS)
    live = pe_mjx.load_policy(metric, "pursuer", deterministic=True, env_config=scene)
    radii = pe_mjx.load_policy(RUN, "pursuer", deterministic=True, env_config=scene)
    policy, key = load(path), jax.random.key(0)
    differs = False
    for obs in _observations(8):
        got, _ = policy.apply(obs)
        np.testing.assert_array_equal(got, live(obs, key))
        differs |= not np.array_equal(got, radii(obs, key))
    assert differs


def _live_logits(run: Path):
    from pe_mjx.policy.inference import normalize_obs
    from pe_mjx.policy.store import restore_policy_params

    restored = restore_policy_params(run, "pursuer")
    network, state = restored.network, restored.variables

    def logits(obs):
        return network.apply(state["params"], normalize_obs(obs, state["normalizer"]))[0]

    return logits


_LOADER_SCRIPT = textwrap.dedent(
    """\
    import importlib.abc, importlib.util, sys

    BLOCKED = {blocked!r}

    class Blocker(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked: {{name}}")
            return None

    sys.meta_path.insert(0, Blocker())
    try:
        import flax  # noqa: F401
    except ImportError as err:
        print(err)
    spec = importlib.util.spec_from_file_location("export_loader", {loader!r})
    loader = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loader)

    import numpy as np

    policy = loader.load(sys.argv[1])
    data = np.load(sys.argv[2])
    cases = {{}}
    for key in data.files:
        i, name = key.split("/")
        cases.setdefault(i, {{}})[name] = data[key]
    out = {{}}
    for i, obs in cases.items():
        actions, logits = policy.apply(obs)
        out[f"{{i}}/actions"], out[f"{{i}}/logits"] = np.asarray(actions), np.asarray(logits)
    v, omega = policy.commands(cases["0"])
    assert v.shape == omega.shape == (4,)
    np.savez(sys.argv[3] + "/out.npz", **out)
    leaked = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    assert not leaked, leaked
    """
)


def test_file_layout_and_controller(exported):
    """The file is a zip of the program and readable metadata; the deployment controller runs
    the loaded policy as it runs a live one."""
    with zipfile.ZipFile(exported) as archive:
        assert sorted(archive.namelist()) == ["meta.json", "policy.stablehlo"]
        meta = json.loads(archive.read("meta.json"))
    assert meta["counts"] == {"pursuers": 4, "evaders": 2, "obstacles": 2}
    assert meta["env_config"]["pursuer"]["min_turning_radius"] == 0.4
    assert set(meta["platforms"]) == {"cpu", "cuda"}
    policy = load(exported)
    config = get_preset(ROBOTS)
    ctrl = Controller(config, {"pursuer": policy})
    ctrl.update_team("pursuer", [[-1, 0, 0], [1, 0, 3.1], [0, 1, -1.5], [0, -1, 1.5]], 0.0)
    ctrl.update_team("evader", [[-2, 1.5, 0], [2, -1.5, 0]], 0.0)
    commands = ctrl.act([[0.0, 1.8, 0.4], [0.0, -1.8, 0.3]])["pursuer"]
    obs = ctrl.observe([[0.0, 1.8, 0.4], [0.0, -1.8, 0.3]])["pursuer"]
    v, omega = policy.commands(obs)
    np.testing.assert_array_equal(commands, np.stack([v, omega], axis=-1))


def test_loader_refuses_bad_input(exported, tmp_path):
    policy = load(exported)
    obs = {name: np.zeros(shape, dtype) for name, shape, dtype in policy.inputs}
    big = {**obs, "obstacles": np.zeros((2, 5, 4), np.float32)}
    with pytest.raises(ValueError, match=r"obstacles has shape \(2, 5, 4\).*at most"):
        policy.apply(big)
    with pytest.raises(ValueError, match="no 'action_mask'"):
        policy.apply({k: v for k, v in obs.items() if k != "action_mask"})
    bad = tmp_path / "bad.jaxexport"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="is not a pe-mjx exported policy"):
        load(bad)


def test_a_device_a_pipe_or_a_directory_is_refused_before_it_is_read(tmp_path):
    """`load("/dev/zero")` read until the kernel killed the process (zipfile seeks, then reads
    to the end); a FIFO waited for a writer."""
    fifo = tmp_path / "policy.jaxexport"
    os.mkfifo(fifo)
    for path, kind in (("/dev/zero", "a device or a pipe"), (fifo, "a device or a pipe"),
                       (tmp_path, "a directory")):  # fmt: skip
        with pytest.raises(ValueError, match=f"cannot read it: it is {kind}, not a policy file"):
            load(path)


def test_cli_errors_are_one_line(exported, tmp_path, capsys):
    cases = [
        (["export", str(tmp_path / "nope"), "-o", str(tmp_path / "a")], "no run at"),
        (["export", str(RUN), "-o", str(exported)], "exists; pass --force"),
        (["export", str(RUN), "-o", str(tmp_path / "no" / "a")], "does not exist"),
        (["export", str(RUN), "-o", str(tmp_path)], "is a directory"),
        (["export", str(RUN), "--team", "referee"], "referee"),
        (["export", str(RUN), "--preset", "3-3-3"], "3-3-3"),
    ]
    for argv, message in cases:
        with pytest.raises(SystemExit) as exit_:
            cli.main(argv)
        assert exit_.value.code == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("pe-mjx: error: ") and message in err, (argv, err)
        assert len(err.strip().splitlines()) == 1, err


def _rewritten(source: Path, path: Path, meta_change=None, program: bytes | None = None) -> Path:
    """A copy of `source` with its metadata changed by `meta_change(meta)` and/or its program
    replaced (a well-formed zip: only the content is wrong)."""
    with zipfile.ZipFile(source) as archive:
        meta = json.loads(archive.read("meta.json"))
        original = archive.read("policy.stablehlo")
    if meta_change is not None:
        meta_change(meta)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("meta.json", json.dumps(meta))
        archive.writestr("policy.stablehlo", original if program is None else program)
    return path


def _load_outcome(path: Path) -> str:
    """ "ok", or "ValueError: ..." (anything else fails the test at once)."""
    try:
        load(path)
    except ValueError as err:
        assert str(err).startswith(str(path)), err
        assert "\n" not in str(err), err
        return f"ValueError: {err}"
    return "ok"


def test_every_truncation_and_flipped_byte_is_a_value_error(exported, tmp_path):
    """Deterministic fuzzing of a real exported file: truncated at every length of its head and
    tail and at a stride between, and every byte of its zip headers (and a stride of its
    compressed data) inverted. Each either raises ValueError naming the file, or (a byte zip
    does not use: a timestamp, the "made by" version) loads the same policy."""
    data = exported.read_bytes()
    n = len(data)
    original = load(exported)
    path = tmp_path / "fuzz.jaxexport"
    lengths = sorted({*range(0, 600), *range(n - 600, n), *range(600, n - 600, 211)})
    for length in lengths:
        path.write_bytes(data[:length])
        assert _load_outcome(path).startswith("ValueError"), length
    # The zip's structures: both local headers, the central directory and its end record.
    central = data.rfind(b"PK\x01\x02", 0, data.rfind(b"PK\x01\x02"))
    second_local = data.find(b"PK\x03\x04", 4)
    headers = {*range(0, 120), *range(second_local, second_local + 120), *range(central, n)}
    positions = sorted(headers | set(range(0, n, 97)))
    outcomes = {"ok": 0, "error": 0}
    for i in positions:
        flipped = bytearray(data)
        flipped[i] ^= 0xFF
        path.write_bytes(bytes(flipped))
        outcome = _load_outcome(path)
        if outcome == "ok":
            outcomes["ok"] += 1
            again = load(path)
            assert again.meta == original.meta and again.inputs == original.inputs, i
        else:
            outcomes["error"] += 1
    print(f"{len(lengths)} truncations, {len(positions)} flipped bytes: {outcomes}")
    assert outcomes["error"] > 0.8 * len(positions)


def test_malformed_contents_are_value_errors_before_any_allocation(exported, tmp_path):
    """Well-formed zips with wrong contents, and headers that declare huge sizes."""
    cases = {
        "wrong_magic": None,
        "huge_program_size": None,
        "no_meta": None,
        "format": (lambda m: m.pop("format"), "format tag missing"),
        "version_2": (lambda m: m.__setitem__("version", 2), "format version 2"),
        "team": (lambda m: m.__setitem__("team", "referee"), "team must be one of"),
        "inputs_not_list": (lambda m: m.__setitem__("inputs", {}), "inputs must be"),
        "dtype_float64": (
            lambda m: m["inputs"][0].__setitem__("dtype", "float64"),
            "input 'own' has dtype 'float64'",
        ),
        "dtype_object": (lambda m: m["inputs"][1].__setitem__("dtype", "object"), "has dtype"),
        "shape_negative": (lambda m: m["inputs"][0].__setitem__("shape", [-4, 5]), "has shape"),
        "shape_huge": (
            lambda m: m["inputs"][2].__setitem__("shape", [60000, 60000, 6]),
            "more than",
        ),
        "shape_float": (lambda m: m["inputs"][0].__setitem__("shape", [4.0, 5]), "has shape"),
        "shape_disagrees_with_program": (
            lambda m: m["inputs"][0].__setitem__("shape", [4, 6]),
            "its program takes",
        ),
        "agent_counts_differ": (
            lambda m: m["inputs"][0].__setitem__("shape", [3, 5]),
            "disagree on the agent count",
        ),
        "actions_table_short": (
            lambda m: m["action_table"].__setitem__("v", m["action_table"]["v"][:-1]),
            "differ in length",
        ),
        "actions_table_nan": (
            lambda m: m["action_table"]["omega"].__setitem__(0, float("nan")),
            "finite numbers",
        ),
        "actions_table_missing": (lambda m: m.pop("action_table"), "action_table is missing"),
        "garbage_program": (None, "program cannot be read"),
        "empty_program": (None, "program cannot be read"),
    }
    data = exported.read_bytes()
    for name, case in cases.items():
        path = tmp_path / f"{name}.jaxexport"
        if name == "wrong_magic":
            path.write_bytes(b"XX" + data[2:])
            message = "is not a pe-mjx exported policy"
        elif name == "huge_program_size":
            # The central directory's uncompressed size of the program: 4 GB.
            central = data.rfind(b"PK\x05\x06")  # the end record; the directory is before it
            entry = data.rfind(b"PK\x01\x02", 0, data.rfind(b"policy.stablehlo", 0, central))
            crafted = bytearray(data)
            crafted[entry + 24 : entry + 28] = (0xFFFFFFF0).to_bytes(4, "little")
            path.write_bytes(bytes(crafted))
            message = "declares 4,294,967,280 bytes"
        elif name == "no_meta":
            with zipfile.ZipFile(path, "w") as archive:
                archive.writestr("policy.stablehlo", b"x")
            message = "has no meta.json member"
        elif case[0] is None:  # the program replaced
            program = b"" if name == "empty_program" else bytes(range(256)) * 40
            _rewritten(exported, path, program=program)
            message = case[1]
        else:
            _rewritten(exported, path, meta_change=case[0])
            message = case[1]
        outcome = _load_outcome(path)
        assert outcome.startswith("ValueError") and message in outcome, (name, outcome)


def test_exported_policy_refuses_non_finite_observations_and_empty_masks(exported):
    policy = load(exported)
    obs = _observations(1)[0]
    policy(obs)  # valid
    bad = {**obs, "opponents": obs["opponents"].copy()}
    bad["opponents"][1, 0, 2] = np.nan
    with pytest.raises(ValueError, match=r"observation opponents holds nan at \[1, 0, 2\]"):
        policy(bad)
    bad = {**obs, "own": obs["own"].copy()}
    bad["own"][0, 0] = np.inf
    with pytest.raises(ValueError, match="observation own holds inf"):
        policy.commands(bad)
    mask = obs["action_mask"].copy()
    mask[2] = False
    with pytest.raises(ValueError, match=r"action_mask allows no action for agent\(s\) \[2\]"):
        policy({**obs, "action_mask": mask})
