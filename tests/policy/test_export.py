"""`pe-mjx export` (pe_mjx.policy.export) and its stand-alone loader
(pe_mjx/policy/export_loader.py)."""

from __future__ import annotations

import contextlib
import io
import json
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
from tests.tool_modules import load_tool

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
    """The shipped pursuers reading neighbour lengths in units of 5 m (`ship_policy.py
    --length-unit 5`), exported for 4-2-2 (a 3 m arena): the file acts as the live policy
    resolved for that scene, not as the same parameters reading arena radii."""
    tool = load_tool("ship_policy")
    metric = tool.ship(tool.Args(RUN, "m5", dest=tmp_path, length_unit=5.0))
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
