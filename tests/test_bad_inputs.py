"""The CLI's error contract, table-driven: every bad flag, value, path or damaged file of every
subcommand ends with exactly one line `pe-mjx: error: ...`, exit code 2, no traceback, and
leaves the file system as it was. Cases run in-process through `pe_mjx.cli.main` and all fail
before anything is compiled; the test prints "N tried, N clear errors" for the CI log."""

from __future__ import annotations

import gzip
import json
import lzma
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pe_mjx.cli import main
from pe_mjx.ppo.checkpoint import lock_run
from pe_mjx.ppo.curves import CURVES_FILE, LEGACY_FILE
from tests.policy_copies import orbax_copy
from tests.ratings.test_board import TABLE_III

BIG = str(2**63)
HUGE = str(2**64)
TINY_TRAIN = ["--preset", "2-1-1", "--backend", "kinematic", "--no-progress"]


# Damaged copies of a shipped policy run: name -> change to its metadata (a dict) or a file edit.
META_DAMAGE = {
    "num_actions_off_by_one": lambda m: m["num_actions"].__setitem__(
        "pursuer", m["num_actions"]["pursuer"] + 1
    ),
    "num_actions_string": lambda m: m["num_actions"].__setitem__("pursuer", "39"),
    "wrong_typed_setting": lambda m: m["env_config"].__setitem__("max_steps", "100"),
    "num_agents_20000": lambda m: m["env_config"]["pursuer"].__setitem__("num_agents", 20000),
    "num_obstacles_huge": lambda m: m["env_config"]["arena"].__setitem__("num_obstacles", 10**6),
    "negative_radius": lambda m: m["env_config"]["arena"].__setitem__("radius", -1.0),
    "unknown_env_field": lambda m: m["env_config"].__setitem__("gravity", 9.81),
    "missing_env_config": lambda m: m.pop("env_config"),
    "missing_num_actions": lambda m: m.pop("num_actions"),
    "format_99": lambda m: m.__setitem__("format_version", 99),
    "format_string": lambda m: m.__setitem__("format_version", "2"),
    "format_2_without_experiment": lambda m: (
        m.__setitem__("format_version", 2),
        m.pop("experiment", None),
    ),
    "network_configs_list": lambda m: m.__setitem__("network_configs", []),
    "network_configs_empty": lambda m: m.__setitem__("network_configs", {}),
    "network_unknown_team": lambda m: m["network_configs"].__setitem__("referee", {}),
    "network_width_huge": lambda m: m["network_configs"]["pursuer"].__setitem__("width", 10**6),
    "network_bad_encoder": lambda m: m["network_configs"]["pursuer"].__setitem__(
        "encoder", "transformer"
    ),
    "network_width_wrong": lambda m: m["network_configs"]["pursuer"].__setitem__("width", 64),
    "iteration_negative": lambda m: m.__setitem__("iteration", -1),
    "env_steps_float": lambda m: m.__setitem__("env_steps", 1.5),
}


def _file_damage(step: Path, kind: str) -> None:
    if kind == "meta_truncated":
        meta = step / "meta" / "metadata"
        meta.write_bytes(meta.read_bytes()[:50])
    elif kind == "meta_list":
        (step / "meta" / "metadata").write_text("[1, 2, 3]")
    elif kind == "meta_binary":
        (step / "meta" / "metadata").write_bytes(os.urandom(256))
    elif kind == "params_truncated":
        for f in (step / "policy_pursuer").rglob("*"):
            if f.is_file() and f.stat().st_size > 0:
                f.write_bytes(f.read_bytes()[: f.stat().st_size // 3])
    elif kind == "params_zeroed":
        for f in (step / "policy_pursuer").rglob("*"):
            if f.is_file() and f.stat().st_size > 16:
                f.write_bytes(b"\0" * f.stat().st_size)
    elif kind == "params_missing":
        shutil.rmtree(step / "policy_pursuer")
    elif kind == "manifest_garbage":
        (step / "policy_pursuer" / "manifest.ocdbt").write_bytes(b"garbage" * 10)
    elif kind == "checkpoints_is_a_file":
        shutil.rmtree(step.parent)
        step.parent.write_text("not a directory")
    elif kind == "only_unfinished_step":
        step.rename(step.parent / f"{step.name}.orbax-checkpoint-tmp-1")
    elif kind == "no_checkpoints":
        shutil.rmtree(step.parent)


FILE_DAMAGE = (
    "meta_truncated",
    "meta_list",
    "meta_binary",
    "params_truncated",
    "params_zeroed",
    "params_missing",
    "manifest_garbage",
    "checkpoints_is_a_file",
    "only_unfinished_step",
    "no_checkpoints",
)
DAMAGED = (*META_DAMAGE, *FILE_DAMAGE)


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    """A scratch tree: files, directories, damaged runs, bad config and replay files."""
    root = tmp_path_factory.mktemp("bad-inputs")
    (root / "afile").write_text("a file")
    (root / "existing.xml").write_text("precious")
    (root / "adir").mkdir()
    (root / "emptydir").mkdir()
    (root / "results").mkdir()
    (root / "results" / "results.md").write_text("old results")
    shipped = orbax_copy("mix-20-5-8", root / "orbax-copy")
    runs = root / "runs"
    for name in DAMAGED:
        run = runs / name
        shutil.copytree(shipped, run, symlinks=False)
        step = next(p for p in (run / "checkpoints").iterdir() if p.name.isdigit())
        if name in META_DAMAGE:
            path = step / "meta" / "metadata"
            meta = json.loads(path.read_text())
            META_DAMAGE[name](meta)
            path.write_text(json.dumps(meta))
        else:
            _file_damage(step, name)
    shutil.copytree(shipped, runs / "good")
    (root / "locked").mkdir()
    configs = root / "configs"
    configs.mkdir()
    (configs / "broken.json").write_text("{not json")
    (configs / "list.json").write_text("[1, 2]")
    (configs / "list.yaml").write_text("- 1\n- 2\n")
    (configs / "unknown.json").write_text(json.dumps({"ppo": {"learning_speed": 1}}))
    (configs / "wrongtype.json").write_text(json.dumps({"ppo": {"num_envs": "64"}}))
    (configs / "nan.json").write_text('{"ppo": {"learning_rate": NaN}}')
    (configs / "gamma.yaml").write_text("ppo:\n  gamma: 2.0\n")
    (configs / "huge.json").write_text(" " * 1_100_000 + "{}")
    (configs / "binary.json").write_bytes(os.urandom(512))
    (configs / "bothfixed.json").write_text(
        json.dumps({"pursuer": {"policy": "scripted"}, "evader": {"policy": "scripted"}})
    )
    replays = root / "replays"
    replays.mkdir()
    (replays / "empty.npz").write_bytes(b"")
    (replays / "random.npz").write_bytes(os.urandom(4096))
    (replays / "text.npz").write_text("not a zip")
    import zipfile

    with zipfile.ZipFile(replays / "emptyzip.npz", "w"):
        pass
    with zipfile.ZipFile(replays / "junkzip.npz", "w") as z:
        z.writestr("pos.npy", b"\x93NUMPY junk")
    _crafted_inputs(root, shipped)
    return root


def _crafted_inputs(root: Path, shipped: Path) -> None:
    """Files of a careless or hostile user: odd names, links to nothing, keys given twice,
    crafted replays, curves and results, a pipe where a file should be."""
    import numpy as np

    from tests.test_trajectory import make, raw

    (root / "new\nline.xml").write_text("precious")
    (root / "dangling").symlink_to(root / "missing-target")
    (root / "loop-a").symlink_to(root / "loop-b")
    (root / "loop-b").symlink_to(root / "loop-a")
    configs = root / "configs"
    (configs / "dup.yaml").write_text("ppo:\n  num_envs: 8\nppo:\n  gamma: 0.5\n")
    (configs / "dup.json").write_text('{"ppo": {"num_envs": 8}, "ppo": {"gamma": 0.5}}')
    (configs / "name_list.json").write_text('{"env": {"name": ["2-1-1"]}}')
    replays = root / "replays"
    deep = raw(make())
    deep["config_json"] = np.asarray("[" * 100_000 + "]" * 100_000)
    np.savez(replays / "deep_json.npz", **deep)
    far = raw(make())
    far["poses"] = far["poses"] * np.float32(1e30)
    np.savez(replays / "far_poses.npz", **far)
    curves = root / "curves"
    for name, row, file in (("inf_steps", "1e400,1,0.5", CURVES_FILE),
                            ("nan_value", "100,1,nan", CURVES_FILE),
                            ("negative_steps", "-100,1,0.5", CURVES_FILE),
                            ("legacy_gzip_nan", "100,1,nan", LEGACY_FILE)):  # fmt: skip
        (curves / name).mkdir(parents=True)
        text = f"env_steps,wall_time,eval/pursuer_vs_scripted/success_rate\n{row}\n".encode()
        packed = gzip.compress(text) if file == LEGACY_FILE else lzma.compress(text)
        (curves / name / file).write_bytes(packed)
    for name in ("tb_garbage", "tb_zero", "tb_fifo"):
        (curves / name / "tb").mkdir(parents=True)
    record = b"\xff\xff\xff\xff\x0f"  # not an Event protobuf
    (curves / "tb_garbage" / "tb" / "events.out.tfevents.1").write_bytes(
        len(record).to_bytes(8, "little") + bytes(4) + record + bytes(4)
    )
    (curves / "tb_zero" / "tb" / "events.out.tfevents.1").symlink_to("/dev/zero")
    os.mkfifo(curves / "tb_fifo" / "tb" / "events.out.tfevents.1")
    fifo_run = root / "runs" / "fifo_config"
    shutil.copytree(shipped, fifo_run)
    (fifo_run / "config.json").unlink()
    os.mkfifo(fifo_run / "config.json")
    # 1,001 pursuer policies against one evader: a fit of dense [J, C] matrices.
    results = json.loads(TABLE_III.read_text())
    pairing = results["pairings"][0]
    pairing["trials"] = {"evaders_incapacitated": pairing["trials"]["evaders_incapacitated"]}
    many = []
    for i in range(1001):
        one = json.loads(json.dumps(pairing))
        one["pursuer"] = {"source": f"p{i}", "label": f"P{i}"}
        many.append(one)
    results["pairings"] = many
    results["meta"]["pursuers"] = [f"p{i}" for i in range(1001)]
    results["meta"]["evaders"] = [pairing["evader"]["source"]]
    (root / "many_policies.json").write_text(json.dumps(results))


def _cases(w: Path) -> list[tuple[str, list[str]]]:
    runs = w / "runs"
    cases: list[tuple[str, list[str]]] = []

    def add(name: str, *argv: str) -> None:
        cases.append((name, list(argv)))

    # ---- top level
    add("no-subcommand-unknown", "frobnicate")
    add("unknown-top-flag", "--frobnicate")
    # ---- scene
    for seed in ("-1", str(2**32), BIG, HUGE, "abc", "1.5", ""):
        add(f"scene-seed-{seed[:6]}", "scene", "--seed", seed, "-o", str(w / "s.xml"))
    add("scene-preset", "scene", "--preset", "nope", "-o", str(w / "s.xml"))
    add("scene-output-dir", "scene", "-o", str(w / "adir"), "--force")
    add("scene-output-missing-dir", "scene", "-o", str(w / "missing" / "a.xml"))
    add("scene-output-under-file", "scene", "-o", str(w / "afile" / "a.xml"))
    add("scene-output-exists", "scene", "-o", str(w / "existing.xml"))
    add("scene-unknown-flag", "scene", "--no-such-flag")
    add("scene-missing-value", "scene", "--preset")
    add("scene-force-value", "scene", "--force=maybe")
    add("scene-extra-positional", "scene", "extra")
    # ---- demo
    for seed in ("-1", str(2**32), BIG, HUGE, "x"):
        add(f"demo-seed-{seed[:6]}", "demo", "--seed", seed)
    for steps in ("0", "-5", "abc", "1e3"):
        add(f"demo-steps-{steps}", "demo", "--steps", steps)
    add("demo-backend", "demo", "--backend", "warp")
    add("demo-preset", "demo", "--preset", "1-1-1")
    add("demo-unknown-flag", "demo", "--pursuers", "scripted")
    # ---- evaluate
    ev = ["evaluate", "--preset", "2-1-1", "--backend", "kinematic", "--trials", "2"]
    ev_out = ["--out", str(w / "ev")]
    add("evaluate-empty-pursuers", *ev, *ev_out, "--pursuers")
    add("evaluate-empty-evaders", *ev, *ev_out, "--evaders")
    for record in ("-1", "-100", "abc"):
        add(f"evaluate-record-{record}", *ev, *ev_out, "--record", record)
    for trials in ("0", "-3", str(10**9), "1.5"):
        add(f"evaluate-trials-{trials}", *ev[:-1], trials, *ev_out)
    for seed in ("-1", str(2**32), BIG, HUGE):
        add(f"evaluate-seed-{seed[:6]}", *ev, *ev_out, "--seed", seed)
    add("evaluate-backend", "evaluate", "--backend", "warp", *ev_out)
    add("evaluate-preset", "evaluate", "--preset", "nope", *ev_out)
    add("evaluate-out-file", *ev, "--out", str(w / "afile"))
    add("evaluate-out-under-file", *ev, "--out", str(w / "afile" / "sub"))
    add("evaluate-out-has-results", *ev, "--out", str(w / "results"))
    add("evaluate-pursuer-missing", *ev, *ev_out, "--pursuers", "no-such-run")
    add("evaluate-pursuer-empty-string", *ev, *ev_out, "--pursuers", "")
    add("evaluate-pursuer-file", *ev, *ev_out, "--pursuers", str(w / "afile"))
    add("evaluate-pursuer-plain-dir", *ev, *ev_out, "--pursuers", str(w / "adir"))
    add("evaluate-evader-missing", *ev, *ev_out, "--evaders", "scripted", "nope")
    add("evaluate-unknown-flag", *ev, *ev_out, "--episodes", "3")
    add("evaluate-env-count", *ev, *ev_out, "--env.pursuer.num-agents", "0")
    add("evaluate-env-radius", *ev, *ev_out, "--env.arena.radius", "nan")
    add("evaluate-env-unknown", *ev, *ev_out, "--env.arena.walls", "3")
    add("evaluate-config-missing", *ev, *ev_out, "--config", str(w / "none.json"))
    add("evaluate-config-not-json", *ev, *ev_out, "--config", str(w / "afile"))
    add("evaluate-config-resume", *ev, *ev_out, "--resume", str(w / "adir"))
    for name in DAMAGED:
        add(f"evaluate-damaged-{name}", *ev, *ev_out, "--pursuers", str(runs / name))
    # ---- view (all fail before the server starts)
    vw = ["view", "--preset", "2-1-1", "--backend", "kinematic"]
    for port in ("-1", "70000", "http"):
        add(f"view-port-{port}", *vw, "--port", port)
    for seed in ("-1", BIG, HUGE):
        add(f"view-seed-{seed[:6]}", *vw, "--seed", seed)
    for speed in ("nan", "inf", "-1"):
        add(f"view-speed-{speed}", *vw, "--speed", speed)
    for arenas in ("0", "65", "-2"):
        add(f"view-arenas-{arenas}", *vw, "--arenas", arenas)
    add("view-backend", "view", "--backend", "warp")
    add("view-preset", "view", "--preset", "nope", "--backend", "kinematic")
    add("view-steps", *vw, "--export", str(w / "exp"), "--steps", "0")
    add("view-trail-length", *vw, "--trail-length", "0")
    for hold in ("nan", "-1"):
        add(f"view-hold-{hold}", *vw, "--hold", hold)
    add("view-record-dir-file", *vw, "--record-dir", str(w / "afile"))
    add("view-policy-roots-missing", *vw, "--policy-roots", str(w / "missing"))
    add("view-pursuers-missing", *vw, "--pursuers", "no-such-run")
    add("view-evaders-file", *vw, "--evaders", str(w / "afile"))
    add("view-replay-missing", *vw, "--replay", str(w / "missing.npz"))
    for replay in sorted((w / "replays").iterdir()):
        add(f"view-replay-{replay.stem}", *vw, "--replay", str(replay))
    for name in ("num_actions_off_by_one", "num_agents_20000", "params_truncated", "meta_binary"):
        add(f"view-damaged-{name}", *vw, "--pursuers", str(runs / name))
    # ---- train: every hyperparameter range, paths, configs, resume
    out = ["--out", str(w / "run")]
    bad_values = {
        "--ppo.learning-rate": ("nan", "inf", "-1e-4", "0", "fast"),
        "--ppo.gamma": ("2", "0", "-0.5", "nan"),
        "--ppo.gae-lambda": ("0", "1.5", "inf"),
        "--ppo.clip-epsilon": ("-0.2", "0"),
        "--ppo.max-grad-norm": ("0", "-1"),
        "--ppo.value-coef": ("-1", "nan"),
        "--ppo.entropy-coef": ("-0.01", "inf"),
        "--ppo.num-envs": ("0", "-1", "abc", "2.5"),
        "--ppo.unroll-length": ("0", "-4"),
        "--ppo.update-epochs": ("0",),
        "--ppo.num-minibatches": ("0", "100000"),
        "--ppo.lr-schedule": ("cosine",),
        "--env-steps": ("0", "-1", "1e6"),
        "--seed": ("-1", str(2**32), BIG, HUGE),
        "--eval-every": ("-1",),
        "--eval-envs": ("0",),
        "--checkpoint-every": ("0", "-5"),
        "--stop-after": ("0", "-1"),
        "--backend": ("warp",),
        "--preset": ("nope",),
        "--pursuer.network.encoder": ("transformer",),
        "--pursuer.network.width": ("0",),
        "--pursuer.network.num-heads": ("3", "0"),
        "--pursuer.network.hidden": ("0",),
        "--evader.network.nearest-k": ("0",),
        "--pursuer.reward-scale": ("0", "nan", "-1"),
        "--env.reward.capture": ("nan", "inf"),
        "--env.arena.radius": ("inf", "-1"),
        "--env.max-steps": ("0",),
        "--pool.team": ("referee",),
        "--pool.keep": ("0",),
        "--pool.snapshot-every": ("0", "-2"),
        "--pool.p-current": ("nan", "-1"),
        "--pool.fixed": ("learn",),
    }
    for flag, values in bad_values.items():
        for value in values:
            add(f"train{flag}-{value[:6]}", "train", *TINY_TRAIN, *out, flag, value)
    add("train-both-fixed", "train", *TINY_TRAIN, *out, "--pursuer.policy", "scripted",
        "--evader.policy", "scripted")  # fmt: skip
    add("train-opponent-missing", "train", *TINY_TRAIN, *out, "--evader.policy", "no-such-run")
    add("train-opponent-damaged", "train", *TINY_TRAIN, *out, "--evader.policy",
        str(runs / "num_actions_off_by_one"))  # fmt: skip
    add("train-init-scripted", "train", *TINY_TRAIN, *out, "--evader.init", "scripted")
    add("train-init-missing", "train", *TINY_TRAIN, *out, "--evader.init", "no-such-run")
    add("train-init-fixed-team", "train", *TINY_TRAIN, *out, "--evader.policy", "random",
        "--evader.init", str(runs / "good"))  # fmt: skip
    add("train-init-misfit", "train", *TINY_TRAIN, *out, "--pursuer.network.width", "8",
        "--pursuer.init", str(runs / "good"))  # fmt: skip
    add("train-pool-probabilities", "train", *TINY_TRAIN, *out, "--pool.team", "pursuer",
        "--pool.p-current", "0.5")  # fmt: skip
    add("train-pool-fixed-opponent", "train", *TINY_TRAIN, *out, "--pool.team", "pursuer",
        "--evader.policy", "scripted")  # fmt: skip
    add("train-pools-fixed-opponent", "train", *TINY_TRAIN, *out, "--pool.team", "both",
        "--pursuer.policy", "scripted")  # fmt: skip
    for name, member in (("missing", "no-such-run"), ("damaged", "num_actions_off_by_one")):
        add(f"train-pool-member-{name}", "train", *TINY_TRAIN, *out, "--pool.team", "pursuer",
            "--pool.fixed", member if name == "missing" else str(runs / member),
            "--pool.p-current", "0.5", "--pool.p-fixed", "0.5")  # fmt: skip
    add("train-unknown-flag", "train", *TINY_TRAIN, *out, "--learning-rate", "1e-3")
    add("train-missing-value", "train", *TINY_TRAIN, *out, "--ppo.gamma")
    add("train-view-value", "train", *TINY_TRAIN, *out, "--view=maybe")
    add("train-out-file", "train", *TINY_TRAIN, "--out", str(w / "afile"))
    add("train-out-under-file", "train", *TINY_TRAIN, "--out", str(w / "afile" / "run"))
    add("train-out-holds-run", "train", *TINY_TRAIN, "--out", str(runs / "good"))
    add("train-out-locked", "train", *TINY_TRAIN, "--out", str(w / "locked"))
    for config in sorted((w / "configs").iterdir()):
        add(f"train-config-{config.name}", "train", "--config", str(config), *out)
    add("train-config-missing", "train", "--config", str(w / "missing.json"), *out)
    add("train-config-dir", "train", "--config", str(w / "adir"), *out)
    add("train-resume-missing", "train", "--resume", str(w / "missing"))
    add("train-resume-file", "train", "--resume", str(w / "afile"))
    add("train-resume-empty", "train", "--resume", str(w / "emptydir"))
    add("train-resume-policy-only", "train", "--resume", str(runs / "good"))
    add("train-resume-with-preset", "train", "--resume", str(runs / "good"), "--preset", "2-1-1")
    add("train-resume-with-config", "train", "--resume", str(runs / "good"), "--config",
        str(w / "configs" / "gamma.yaml"))  # fmt: skip
    add("train-resume-and-out", "train", "--resume", str(runs / "good"), *out)
    for name in ("only_unfinished_step", "meta_truncated", "num_actions_off_by_one"):
        add(f"train-resume-damaged-{name}", "train", "--resume", str(runs / name))
    # --resume-intact: only with --resume; a run with nothing resumable stays as it was.
    add("train-resume-intact-alone", "train", *TINY_TRAIN, *out, "--resume-intact")
    for name in ("good", "meta_truncated", "params_truncated", "only_unfinished_step"):
        add(f"train-resume-intact-{name}", "train", "--resume", str(runs / name),
            "--resume-intact")  # fmt: skip
    # Joining a group: bad timeouts fail before any network is touched.
    group = ["--coordinator-address", "127.0.0.1:1", "--num-processes", "2", "--process-id", "1"]
    for timeout in ("0", "-3", "soon", "1.5", str(10**23)):
        add(f"train-join-timeout-{timeout}", "train", *TINY_TRAIN, *out, *group,
            "--join-timeout", timeout)  # fmt: skip
    # ship --resumable: the copy of a run in progress; nothing is written when refused.
    resumable = ["--dest", str(w / "adir"), "--resumable"]
    add("ship-resumable-no-dest", "ship", str(runs / "good"), "copy", "--resumable")
    add("ship-resumable-nearest-k", "ship", str(runs / "good"), "copy", *resumable,
        "--nearest-k", "4")  # fmt: skip
    add("ship-resumable-bad-name", "ship", str(runs / "good"), "../up", *resumable)
    add("ship-resumable-exists", "ship", str(runs / "good"), "adir", "--dest", str(w),
        "--resumable")  # fmt: skip
    add("ship-resumable-itself", "ship", str(runs / "good"), "good", "--dest", str(runs),
        "--resumable", "--replace")  # fmt: skip
    add("ship-resumable-onto-file", "ship", str(runs / "good"), "afile", "--dest", str(w),
        "--resumable", "--replace")  # fmt: skip
    add("ship-resumable-over-its-folder", "ship", str(runs / "good"), "runs", "--dest", str(w),
        "--resumable", "--replace")  # fmt: skip
    for name in ("good", "meta_truncated", "params_truncated", "only_unfinished_step"):
        add(f"ship-resumable-{name}", "ship", str(runs / name), "copy", *resumable)
    add("ship-resumable-missing", "ship", str(w / "missing"), "copy", *resumable)
    add("ship-resumable-step", "ship", str(runs / "good"), "copy", *resumable, "--step", "7")
    # ---- a careless or hostile user (each was a traceback, a hang, two lines or nonsense taken)
    add("scene-output-newline-exists", "scene", "--preset", "2-1-1", "-o", str(w / "new\nline.xml"))
    add("evaluate-out-dangling-link", *ev, "--out", str(w / "dangling"))
    add("train-out-link-loop", "train", *TINY_TRAIN, "--out", str(w / "loop-a"))
    add("rate-out-link-loop", "rate", str(w / "many_policies.json"), "--out", str(w / "loop-a"))
    add("rate-too-many-policies", "rate", str(w / "many_policies.json"), "--out", str(w / "board"))
    for replay in ("deep_json", "far_poses"):
        add(f"plot-replay-{replay}", "plot", str(w / "replays" / f"{replay}.npz"), "-o",
            str(w / "replay.png"))  # fmt: skip
    for name in sorted(p.name for p in (w / "curves").iterdir()):
        add(f"plot-curves-{name}", "plot", str(w / "curves" / name), "-o", str(w / "curves.png"))
    for name in ("new\nline", " ", "scripted", "a" * 101):
        add(f"ship-name-{name[:8]!r}", "ship", str(runs / "good"), name, "--dest", str(w / "adir"))
    add("train-coordinator-port-superscript", "train", *TINY_TRAIN, *out, "--coordinator-address",
        "127.0.0.1:\u00b2", "--num-processes", "2", "--process-id", "1")  # fmt: skip
    add("ship-config-fifo", "ship", str(runs / "fifo_config"), "copy", "--dest", str(w / "adir"))
    add("plot-fps-huge", "plot", str(w / "replays" / "text.npz"), "-o", str(w / "r.gif"),
        "--fps", "100000")  # fmt: skip
    add("rate-dev-zero", "rate", "/dev/zero", "--out", str(w / "board"))
    return cases


def _snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {  # lstat: the links to nothing (and the loop) are entries of their own
        str(p.relative_to(root)): (p.lstat().st_size, p.lstat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
    }


def _run(argv: list[str], capsys) -> tuple[int | None, str, str, str]:
    """(exit code, stdout, stderr, what was raised other than SystemExit) of one invocation."""
    raised = ""
    code: int | None = 0
    try:
        main(argv)
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else 1
    except BaseException as err:  # a crash: recorded, the table goes on
        raised = f"{type(err).__name__}: {err}"
        code = None
    captured = capsys.readouterr()
    return code, captured.out, captured.err, raised


def test_every_bad_input_gets_one_clear_error(world, capsys, monkeypatch):
    work = world / "cwd"
    work.mkdir(exist_ok=True)
    monkeypatch.chdir(work)  # default outputs (results/latest, runs/...) would land here
    cases = _cases(world)
    unclear = []
    with lock_run(world / "locked"):  # a trainer holds this one
        for name, argv in cases:
            before = _snapshot(world)
            code, out, err, raised = _run(argv, capsys)
            errors = [line for line in err.splitlines() if line.startswith("pe-mjx: error:")]
            problems = []
            if raised:
                problems.append(f"raised {raised[:200]}")
            if code != 2:
                problems.append(f"exit code {code}")
            if len(errors) != 1:
                problems.append(f"{len(errors)} error lines")
            elif err.rstrip("\n").splitlines()[-1] != errors[0]:
                problems.append("the error spans lines")  # a newline in a file name
            if "Traceback" in err + out:
                problems.append("traceback")
            if "pe-mjx: error" in out:
                problems.append("error on stdout")
            if _snapshot(world) != before:
                problems.append("the file system changed")
            if problems:
                unclear.append(f"{name}: {', '.join(problems)} | {err.strip()[-300:]}")
    clear = len(cases) - len(unclear)
    with capsys.disabled():
        print(f"\nbad inputs: {len(cases)} tried, {clear} clear errors")
    assert len(cases) >= 150
    assert not unclear, "\n".join(unclear)


def test_console_script_gives_one_line_and_exit_2(tmp_path):
    """Through the real console script: a seed of 2**63 (an OverflowError traceback before)."""
    exe = Path(sys.executable).parent / "pe-mjx"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "pe_mjx.cli"]
    result = subprocess.run(
        [*cmd, "scene", "--seed", BIG, "-o", "a.xml"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 2
    assert result.stdout == ""
    lines = [x for x in result.stderr.splitlines() if x.startswith("pe-mjx: error:")]
    assert lines == [f"pe-mjx: error: --seed must be in [0, 2**32), got {BIG}"]
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("stated", ["inf", "-5", "lots"])
def test_a_bad_stated_memory_is_one_line_naming_the_variable(stated, tmp_path, capsys, monkeypatch):
    """PE_MJX_MEMORY_BYTES=inf was an OverflowError traceback, -5 blamed --env, lots was
    ignored."""
    monkeypatch.setenv("PE_MJX_MEMORY_BYTES", stated)
    argv = ["train", *TINY_TRAIN, "--out", str(tmp_path / "run")]
    code, out, err, raised = _run(argv, capsys)
    assert (code, raised, out) == (2, "", "")
    assert err == (
        f"pe-mjx: error: PE_MJX_MEMORY_BYTES must be a positive number of bytes (e.g. 64e9), got "
        f"{stated!r}; unset it to use this machine's memory\n"
    )
    assert list(tmp_path.iterdir()) == []


def _console(*args: str, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "pe-mjx"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "pe_mjx.cli"]
    return subprocess.run(
        [*cmd, *args],
        cwd=cwd,
        env={**os.environ, **env},
        capture_output=True,
        timeout=120,
        check=False,
    )


def test_an_unknown_jax_platform_is_one_line_naming_the_variable(tmp_path):
    """JAX_PLATFORMS=bogus (or cuda without CUDA) was JAX's traceback from the first array."""
    result = _console("scene", "-o", "a.xml", cwd=tmp_path, env={"JAX_PLATFORMS": "bogus"})
    assert result.returncode == 2 and result.stdout == b""
    lines = result.stderr.decode().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pe-mjx: error: JAX_PLATFORMS=bogus: JAX "), (
        lines
    )
    assert list(tmp_path.iterdir()) == []


def test_a_name_that_stdout_cannot_encode_is_written_and_printed_escaped(tmp_path):
    """Under PYTHONIOENCODING=utf-8 (strict), the last line, "wrote <name>", of a file name that
    is not UTF-8 was "pe-mjx: error: 'utf-8' codec can't encode ..." after the file was written."""
    name = os.fsdecode(b"arena-\xff.xml")
    env = {"PYTHONIOENCODING": "utf-8"}
    result = _console("scene", "--preset", "2-1-1", "-o", name, cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(b"wrote arena-\\udcff.xml")
    assert [p.name for p in tmp_path.iterdir()] == [name]


@pytest.mark.parametrize("command", ["evaluate", "view"])
def test_a_retired_policy_name_says_what_to_play_instead(command, tmp_path, capsys, monkeypatch):
    """mean-20-5-8 shipped until 2026-12-06: asking for it names its successors."""
    monkeypatch.chdir(tmp_path)
    argv = [command, "--preset", "2-1-1", "--backend", "kinematic", "--pursuers", "mean-20-5-8"]
    code, out, err, raised = _run(argv, capsys)
    assert (code, raised, out) == (2, "", "")
    assert len(err.splitlines()) == 1 and err.startswith("pe-mjx: error: --pursuers: ")
    assert "mean-20-5-8 no longer ships" in err and "play mean-20-5-8-3m or" in err
    assert list(tmp_path.iterdir()) == []
