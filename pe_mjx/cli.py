"""The `pe-mjx` command line: one entry point, one subcommand per job (typed configs via tyro)."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import re
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Literal

import tyro

from pe_mjx import interrupts
from pe_mjx.config import PRESETS, EnvConfig, PresetName
from pe_mjx.experiment import Backend, ExperimentConfig
from pe_mjx.names import BACKENDS, BUILTIN_POLICIES
from pe_mjx.ppo.distributed import DEFAULT_HEARTBEAT_TIMEOUT_S
from pe_mjx.ppo.distributed import FLAGS as GROUP_SETTINGS
from pe_mjx.reproduce import ReproduceArgs
from pe_mjx.viewer.options import ViewerOptions


def _fail(message: str) -> None:
    print(f"pe-mjx: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def _check_preset(name: str) -> None:
    if name not in PRESETS:
        _fail(f"--preset: unknown preset {name!r}; known presets: {', '.join(PRESETS)}")


SEED_LIMIT = 2**32
"""Seeds are in [0, 2**32) (`jax.random.key` keeps 32 bits; larger ones overflowed)."""
MAX_TRIALS = 100_000
"""Episodes per pairing at most (one vmapped batch: more would exhaust memory)."""


def _check_seed(seed: int) -> None:
    if not 0 <= seed < SEED_LIMIT:
        _fail(f"--seed must be in [0, 2**32), got {seed}")


def _check_backend(backend: str) -> None:
    if backend not in BACKENDS:
        _fail(f"--backend: unknown backend {backend!r}; expected {' or '.join(BACKENDS)}")


@dataclasses.dataclass(frozen=True)
class SceneArgs:
    """Write the standalone MJCF of a preset's arena exactly as `env.reset(key(seed))` draws it."""

    preset: PresetName = "20-5-8"
    """Scenario preset (P-E-K: pursuers, evaders, obstacles)."""
    seed: int = 0
    """The seed given to `jax.random.key` for `env.reset`."""
    output: Annotated[Path, tyro.conf.arg(aliases=("-o",))] = Path("arena.xml")
    """Where to write the MJCF."""
    force: bool = False
    """Overwrite an existing output file."""


@dataclasses.dataclass(frozen=True)
class DemoArgs:
    """Play one scripted match (scripted pursuers against scripted evaders) and print the result."""

    preset: PresetName = "8-2-4"
    """Scenario preset (P-E-K: pursuers, evaders, obstacles)."""
    seed: int = 0
    """Seed of the arena draw (`jax.random.key`)."""
    backend: Backend = "kinematic"
    """Env backend: mjx (MuJoCo MJX physics) or kinematic (exact arcs, faster to compile)."""
    steps: int = 1000
    """Control steps at most (the episode may end earlier)."""


@dataclasses.dataclass(frozen=True)
class TrainArgs:
    """Train a pursuer and an evader policy together (IPPO co-evolution), or one against a fixed
    opponent. Every field of the experiment is a flag (--env.reward.capture 50,
    --pursuer.network.encoder mean, --ppo.learning-rate 1e-4); the run directory gets the whole
    tree in config.json, TensorBoard logs in tb/ and checkpoints in checkpoints/."""

    experiment: Annotated[ExperimentConfig, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=ExperimentConfig
    )
    preset: PresetName | None = None
    """Scenario preset (P-E-K) whose game the env flags start from (default 20-5-8)."""
    config: Path | None = None
    """Read the experiment from this JSON or YAML file (a whole tree, a partial one over the
    preset, or a run's config.json); flags given with it override it."""
    out: Path | None = None
    """Run directory (default: runs/<pursuer encoder>-<preset>)."""
    resume: Path | None = None
    """Continue the run in this directory where it stopped, with its saved config. Only
    --env-steps (the budget), --eval-every, --eval-envs and --checkpoint-every may change;
    any other flag that changes the saved config is refused."""
    stop_after: int | None = None
    """Stop (with a checkpoint) after this many iterations; resume later with --resume."""
    progress: bool = True
    """Show the progress bar."""
    view: bool = False
    """Show the latest policies playing in the browser while training runs (viewer on
    http://127.0.0.1:8080, or the next free port)."""
    wandb_project: str | None = None
    """Also log to this Weights & Biases project (pip install 'pe-mjx[wandb]';
    WANDB_MODE=offline logs locally without an account)."""
    coordinator_address: str | None = None
    """Train on several processes (machines, or one per GPU) with jax.distributed: HOST:PORT
    where process 0 serves the coordinator (or JAX_COORDINATOR_ADDRESS). Every process runs the
    same command with its own --process-id; the run directory must be shared."""
    num_processes: int | None = None
    """How many processes train together (or JAX_NUM_PROCESSES)."""
    process_id: int | None = None
    """This process's index in [0, --num-processes) (or JAX_PROCESS_ID); 0 writes the logs."""
    heartbeat_timeout: int = DEFAULT_HEARTBEAT_TIMEOUT_S
    """Seconds without a sign of life after which a process of the group counts as lost."""


GROUP_FLAGS = (*GROUP_SETTINGS.values(), "--heartbeat-timeout")
"""The flags that describe a group of processes, read before the full parse (`join_group`)."""


def _prescan(
    argv: list[str], flags: tuple[str, ...] = ("--preset", "--config", "--resume")
) -> dict[str, str]:
    """The values of `flags` (by default --preset, --config and --resume, which decide the
    defaults of every other flag), read before the full parse."""
    found: dict[str, str] = {}
    for i, arg in enumerate(argv):
        for flag in flags:
            if arg == flag and i + 1 < len(argv):
                found[flag] = argv[i + 1]
            elif arg.startswith(flag + "="):
                found[flag] = arg.split("=", 1)[1]
    return found


def train_defaults(argv: list[str]) -> TrainArgs:
    """The `TrainArgs` whose experiment the flags in `argv` then change: the saved config of a
    resumed run, a config file over a preset, or a preset's defaults."""
    from pe_mjx.experiment import default_config, read_config_file

    found = _prescan(argv)
    preset = found.get("--preset")
    if preset is not None and preset not in PRESETS:
        _fail(f"--preset: unknown preset {preset!r}; known presets: {', '.join(PRESETS)}")
    if "--resume" in found:
        if "--preset" in found or "--config" in found:
            _fail("--resume continues a run with its saved config; drop --preset/--config")
        from pe_mjx.policy.store import CheckpointError
        from pe_mjx.ppo.run import saved_config

        try:
            base = saved_config(found["--resume"])
        except CheckpointError as err:
            _fail(f"--resume: {err}")
    elif "--config" in found:
        base = read_config_file(found["--config"], preset)
    else:
        base = default_config(preset or "20-5-8")
    return TrainArgs(experiment=base)


def join_group(argv: list[str]) -> None:
    """Joins the group of processes that the train flags (or JAX_* variables) describe, before
    anything asks JAX for a device; a lone process does nothing."""
    from pe_mjx.ppo.distributed import group_from, initialize

    found = _prescan(argv, GROUP_FLAGS)
    numbers: dict[str, int] = {}
    for flag in GROUP_FLAGS[1:]:
        if flag in found:
            try:
                numbers[flag] = int(found[flag])
            except ValueError:
                _fail(f"{flag} must be an integer, got {found[flag]!r}")
    try:
        group = group_from(
            found.get("--coordinator-address"),
            numbers.get("--num-processes"),
            numbers.get("--process-id"),
            numbers.get("--heartbeat-timeout", DEFAULT_HEARTBEAT_TIMEOUT_S),
        )
    except ValueError as err:
        _fail(str(err))
    if group is None:
        return
    try:
        initialize(group)
    except Exception as err:  # unreachable coordinator, a port in use: one line
        text = " ".join(str(err).split())[:200]
        _fail(
            f"--coordinator-address: process {group.process_id} of {group.num_processes} cannot "
            f"join the group at {group.coordinator_address}: {text}"
        )


def _check_run_learned(flag: str, spec: str, team: str) -> None:
    """The run `spec` (given as `flag`) has a readable checkpoint that learned `team`."""
    from pe_mjx.policy.store import CheckpointError, read_meta

    try:
        meta = read_meta(spec)
    except CheckpointError as err:
        _fail(f"{flag}: {err}")
    if team not in meta["network_configs"]:
        _fail(f"{flag}: run {spec} did not learn a {team} policy")


def _check_opponents(config: ExperimentConfig) -> None:
    """A team played frozen from a run: its checkpoint is checked before anything is written.
    A team started from one (`init`) is read and checked by `train` itself, before it writes."""
    for team in ("pursuer", "evader"):
        spec = config.team(team).policy
        if spec != "learn" and spec not in BUILTIN_POLICIES:
            _check_run_learned(f"--{team}.policy", spec, team)
        start = config.team(team).init
        if start in BUILTIN_POLICIES:
            _fail(f"--{team}.init: {start} has no parameters; give a run or a shipped policy")


def run_train(args: TrainArgs) -> None:
    from pe_mjx.ppo.checkpoint import CheckpointError, CheckpointWriteError
    from pe_mjx.ppo.distributed import ProcessLostError, is_primary
    from pe_mjx.ppo.run import TrainingError, resume_config, train

    config = args.experiment
    if args.stop_after is not None and args.stop_after < 1:
        _fail(f"--stop-after must be >= 1, got {args.stop_after}")
    if args.view:
        import jax

        if jax.process_count() > 1:
            _fail("--view shows a lone process's training: drop it on several processes")
    if args.resume is None:
        out = args.out or Path("runs") / f"{config.pursuer.network.encoder}-{config.preset}"
        _check_writable_dir("--out", out)
    _check_opponents(config)
    try:
        if args.resume is not None:
            if args.out is not None and args.out.resolve() != args.resume.resolve():
                _fail("--out and --resume name different directories; give only --resume")
            saved = resume_config(args.resume)
            config = resume_config(args.resume, config)
            for field in saved.differences(config):
                old, new = getattr(saved, field), getattr(config, field)
                print(f"pe-mjx train: resuming with {field} {old} -> {new}", flush=True)
            out = args.resume
        else:
            out = args.out or Path("runs") / f"{config.pursuer.network.encoder}-{config.preset}"
        viewer = None
        if args.view:
            from pe_mjx.viewer.app import start_viewer

            viewer = start_viewer(training=True, arenas=1)
            print(f"pe-mjx train: viewer at {viewer.url}", flush=True)
        try:
            _, state = train(
                config,
                out,
                resume=args.resume is not None,
                progress=args.progress,
                stop_after=args.stop_after,
                on_iteration=None if viewer is None else viewer.training_update,
                wandb_project=args.wandb_project,
            )
        finally:
            if viewer is not None:
                viewer.stop()
    except CheckpointWriteError as err:
        # orbax may have left threads waiting forever: end without waiting for them
        interrupts.exit_now(f"pe-mjx: error: {err}", 2)
    except ProcessLostError as err:
        # jax's own exit would wait for the lost process (the group's shutdown barrier), then
        # abort: the checkpoints are on disk, end now.
        interrupts.exit_now(f"pe-mjx: error: {err}", 1)
    except KeyboardInterrupt:
        # Everything worth keeping is on disk by now: checkpoints are written with interrupts
        # held back, and `train` closed its loggers while unwinding. The interpreter's own exit
        # would then join every thread orbax, jax or a logger left behind, and one stuck among
        # them hung a Ctrl-C'd run under load (a flaky CI test): end without waiting.
        interrupts.exit_now("pe-mjx: interrupted", 130)
    except (CheckpointError, TrainingError) as err:
        _fail(str(err))
    if is_primary():
        _training_summary(out, state, config)


def _training_summary(out: Path, state, config: ExperimentConfig) -> None:
    """What the run reached (its last evaluation) and the commands to look at it."""
    from pe_mjx.plots import read_scalars

    print(f"run {out}: {int(state.env_steps):,} env steps, iteration {int(state.iteration)}")
    scalars = read_scalars(out)
    for team, other in (("pursuer", "evader"), ("evader", "pursuer")):
        found = scalars.get(f"eval/{team}_vs_scripted/success_rate")
        if found:
            step, value = found[-1]
            print(
                f"  last evaluation ({step:,} env steps), learned {team}s vs scripted {other}s: "
                f"pursuer success {value:.3f}"
            )
    learned = set(state.teams)
    pursuers = str(out) if "pursuer" in learned else config.pursuer.policy
    evaders = str(out) if "evader" in learned else config.evader.policy
    # A run in a scene of its own (counts or arena of no preset) names it by its config.json.
    preset = config.preset in PRESETS and _same_scene(config.env, PRESETS[config.preset])
    scene = f"--preset {config.preset}" if preset else f"--config {out}/config.json"
    print("next:")
    print(
        f"  pe-mjx evaluate --pursuers {' '.join(dict.fromkeys([pursuers, 'scripted']))} "
        f"--evaders {' '.join(dict.fromkeys([evaders, 'scripted']))} {scene} "
        f"--backend {config.backend} --out {out}/eval"
    )
    if preset:  # the viewer starts from presets only (its GUI changes the counts)
        print(
            f"  pe-mjx view --preset {config.preset} --backend {config.backend} "
            f"--pursuers {pursuers} --evaders {evaders}"
        )
    print(f"  pe-mjx plot {out}")
    print(f"  tensorboard --logdir {out}/tb   (pip install 'pe-mjx[tensorboard]')")


def _same_scene(a: EnvConfig, b: EnvConfig) -> bool:
    """Whether two games have the same arena, teams and timing (their rewards may differ: the
    training defaults add the evaders' flee shaping to a preset's)."""
    return a.replace(reward=b.reward) == b


@dataclasses.dataclass(frozen=True)
class ViewArgs:
    """Watch arenas live in the browser (Viser), replay recorded trajectories, export recordings.

    Prints the local URL; the page shows the arenas in 3D and updates live. With --export it
    writes <export>.viser and <export>.html (a page that plays without a server) and exits."""

    viewer: Annotated[ViewerOptions, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=ViewerOptions
    )
    replay: Path | None = None
    """Replay this trajectory file (.npz written by `pe-mjx evaluate`) instead of a live run."""
    export: Path | None = None
    """Write <export>.viser and <export>.html and exit (the replay, or --steps live steps)."""
    steps: int = 200
    """Live control steps recorded by --export."""


def _check_view_policies(args: ViewArgs) -> None:
    """Loads --pursuers and --evaders once for the preset, so that a bad or damaged one is one
    error line before the server starts."""
    from pe_mjx.config import get_preset
    from pe_mjx.viewer.live import PolicyError, load_team_policy

    config = get_preset(args.viewer.preset)
    for flag, spec, team in (
        ("--pursuers", args.viewer.pursuers, "pursuer"),
        ("--evaders", args.viewer.evaders, "evader"),
    ):
        try:
            load_team_policy(spec, config, team)
        except Exception as err:  # a damaged checkpoint too: one line, never a traceback
            text = " ".join(str(err).split())  # library messages may span many lines
            text = text if len(text) <= 300 else text[:297] + "..."
            if not isinstance(err, PolicyError):
                text = f"cannot load the policy {spec!r} ({type(err).__name__}: {text})"
            _fail(f"{flag}: {text}")


def _check_view_args(args: ViewArgs) -> None:
    import math

    from pe_mjx.viewer.guard import MAX_ARENAS, SEED_MAX, check_address

    o = args.viewer
    if o.arenas is not None and not 1 <= o.arenas <= MAX_ARENAS:
        _fail(f"--arenas must be in 1..{MAX_ARENAS}, got {o.arenas}")
    if o.backend not in BACKENDS:
        _fail(f"--backend: unknown backend {o.backend!r}; expected {' or '.join(BACKENDS)}")
    if not 0 <= o.seed <= SEED_MAX:
        _fail(f"--seed must be in 0..{SEED_MAX}, got {o.seed}")
    if not math.isfinite(o.speed) or o.speed < 0:
        _fail(f"--speed must be a finite number >= 0, got {o.speed}")
    if args.steps < 1:
        _fail(f"--steps must be >= 1, got {args.steps}")
    if o.trail_length < 1:
        _fail(f"--trail-length must be >= 1, got {o.trail_length}")
    if not math.isfinite(o.hold) or o.hold < 0:
        _fail(f"--hold must be a finite number >= 0, got {o.hold}")
    for root in o.policy_roots or ():
        if not root.is_dir():
            _fail(f"--policy-roots: {root} is not a directory")
    if args.export is not None:
        for suffix in (".viser", ".html"):
            if args.export.with_suffix(suffix).exists():
                _fail(f"--export: {args.export.with_suffix(suffix)} exists; refusing to overwrite")
        _check_writable_dir("--export", args.export.parent)
        return
    _check_writable_dir("--record-dir", o.record_dir)
    try:
        check_address(o.host, o.port)  # the viewer warns about a non-local address
    except ValueError as err:
        _fail(str(err))


def _check_writable_dir(flag: str, directory: Path) -> None:
    """`directory` is, or can be created as, a writable directory."""
    existing = directory
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        _fail(f"{flag}: {existing} is not a directory")
    if not os.access(existing, os.W_OK | os.X_OK):
        _fail(f"{flag}: {existing} is not writable")


def run_view(args: ViewArgs) -> None:
    from pe_mjx.trajectory import TrajectoryError

    _check_view_args(args)
    traj = None
    if args.replay is not None:
        from pe_mjx.trajectory import load as load_trajectory

        try:
            traj = load_trajectory(args.replay).select(args.viewer.arenas or 16)
        except TrajectoryError as err:
            _fail(str(err))
    else:
        _check_preset(args.viewer.preset)
        _check_view_policies(args)
    if args.export is not None:
        from pe_mjx.viewer.replay import export_live, export_trajectory

        o = args.viewer
        speed = o.speed / 5.0 if o.speed > 0 else 1.0  # 5 env steps/s is real time
        try:
            if traj is not None:
                paths = export_trajectory(traj, args.export, speed)
            else:
                paths = export_live(
                    o.preset,
                    o.pursuers,
                    o.evaders,
                    o.arenas or 1,
                    o.backend,
                    o.seed,
                    args.steps,
                    args.export,
                    speed,
                )
        except (FileExistsError, TrajectoryError) as err:
            _fail(str(err))
        print(f"wrote {paths[0]} and {paths[1]}")
        return
    from pe_mjx.viewer.app import start_viewer

    options = args.viewer
    if traj is not None:  # the replay's own scene
        options = dataclasses.replace(options, preset=traj.config.name)
    viewer = None
    try:  # a Ctrl-C at any point from here on stops the server it started
        viewer = start_viewer(options, replay=traj, wait=False)
        print(f"pe-mjx view: open {viewer.url} in a browser (Ctrl-C stops the server)", flush=True)
        while True:
            # Short sleeps: a SIGINT delivered to another thread (the server's) only sets a flag
            # that this thread checks when its sleep returns; a long sleep held Ctrl-C back for
            # up to an hour (a CI test that hung).
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        if viewer is not None:
            viewer.stop()


@dataclasses.dataclass(frozen=True)
class EvaluateArgs:
    """Cross-confrontation (paper IV-B to IV-E): every pursuer policy against every evader policy.
    A policy is "scripted", "random", a shipped policy ("mix-20-5-8") or a `pe-mjx train` run
    directory. Writes results.md (the
    paper's table layout), results.csv, trials.csv, results.json, heatmaps and trajectories."""

    env: Annotated[EnvConfig, tyro.conf.arg(name="env")] = dataclasses.field(
        default_factory=lambda: PRESETS["20-5-8"]
    )
    """The scene the trials play, every field a flag as in `pe-mjx train` (--env.pursuer.num-agents
    60 --env.arena.radius 10); its defaults are --preset's (or --config's). Policies trained
    elsewhere play it unchanged: generalization."""
    pursuers: tuple[str, ...] = ("scripted",)
    """Pursuit policies."""
    evaders: tuple[str, ...] = ("scripted",)
    """Evasion policies."""
    preset: PresetName | None = None
    """Scenario preset (P-E-K) whose scene the env flags start from (default 20-5-8)."""
    config: Path | None = None
    """Read the scene from this JSON or YAML file: an env tree (whole or partial, over the
    preset), an experiment tree or a run's config.json (its env); flags given with it override
    it."""
    trials: int = 100
    """Episodes per pairing (one vmapped batch)."""
    seed: int = 0
    """Seed of the trials: trial i of every pairing starts from the same arena."""
    backend: Backend = "mjx"
    """Env backend: mjx (MuJoCo MJX physics) or kinematic (exact arcs, faster to compile)."""
    progress: bool = True
    """Show a progress bar over each pairing's trials (on a terminal, on stderr)."""
    record: int = 3
    """Trials per pairing saved as trajectories for `pe-mjx view --replay`."""
    out: Path = Path("results/latest")
    """Output directory."""


def _check_policy_specs(flag: str, specs: tuple[str, ...], team: str) -> None:
    """Each spec is built in or a readable run that learned `team`: checked before any compile."""
    from pe_mjx.policy.shipped import resolve_run

    if not specs:
        _fail(f"{flag} needs at least one policy (scripted, random, a shipped policy or a run)")
    for spec in specs:
        if spec in BUILTIN_POLICIES:
            continue
        if not spec or not resolve_run(spec).is_dir():
            _fail(f"{flag}: {spec!r} is not scripted, random, a shipped policy or a run directory")
        _check_run_learned(flag, spec, team)


def evaluate_defaults(argv: list[str]) -> EvaluateArgs:
    """The `EvaluateArgs` whose scene the flags in `argv` then change: a config file's scene over
    a preset, or a preset's scene."""
    from pe_mjx.experiment import read_env_file

    found = _prescan(argv)
    preset = found.get("--preset")
    if preset is not None and preset not in PRESETS:
        _fail(f"--preset: unknown preset {preset!r}; known presets: {', '.join(PRESETS)}")
    if "--resume" in found:
        _fail("pe-mjx evaluate has no --resume; name the run in --pursuers or --evaders")
    if "--config" in found:
        try:
            return EvaluateArgs(env=read_env_file(found["--config"], preset))
        except ValueError as err:
            _fail(str(err))
    return EvaluateArgs(env=PRESETS[preset or "20-5-8"])


def _named_scene(env: EnvConfig) -> EnvConfig:
    """The scene under a name that tells what it is in the reports: a preset's name only if it is
    that preset; otherwise its counts ("60-15-30"), with "-custom" when it also differs from the
    preset of those counts (or no preset has them). A name the user gave is kept."""
    if env.name not in PRESETS or PRESETS[env.name] == env:
        return env
    counts = f"{env.pursuer.num_agents}-{env.evader.num_agents}-{env.arena.num_obstacles}"
    if PRESETS.get(counts) == env.replace(name=counts):
        return env.replace(name=counts)
    return env.replace(name=f"{counts}-custom")


def run_evaluate(args: EvaluateArgs) -> None:
    if not 1 <= args.trials <= MAX_TRIALS:
        _fail(f"--trials must be in 1..{MAX_TRIALS}, got {args.trials}")
    if args.record < 0:
        _fail(f"--record must be >= 0 (trials saved per pairing), got {args.record}")
    _check_seed(args.seed)
    _check_backend(args.backend)
    if args.out.exists() and not args.out.is_dir():
        _fail(f"--out: {args.out} is not a directory")
    if args.out.exists() and any(args.out.glob("results.*")):
        _fail(f"--out: {args.out} already holds results; choose another --out")
    _check_writable_dir("--out", args.out)
    _check_policy_specs("--pursuers", args.pursuers, "pursuer")
    _check_policy_specs("--evaders", args.evaders, "evader")
    from pe_mjx.evaluate import evaluate

    report = evaluate(
        list(args.pursuers),
        list(args.evaders),
        _named_scene(args.env),
        args.out,
        args.trials,
        args.seed,
        args.backend,
        min(args.record, args.trials),
        log=lambda line: print(line, file=sys.stderr, flush=True),  # stdout: the table only
        progress=args.progress,
    )
    print(report["paths"]["markdown"].read_text())
    print(f"wrote {args.out} in {report['meta']['seconds']:.1f} s", file=sys.stderr)


def run_scene(args: SceneArgs) -> None:
    _check_preset(args.preset)
    _check_seed(args.seed)
    if args.output.is_dir():
        _fail(f"{args.output} is a directory; give the path of the file to write")
    if args.output.exists() and not args.force:
        _fail(f"{args.output} exists; pass --force to overwrite it")
    if not args.output.parent.is_dir():
        _fail(f"--output: directory {args.output.parent} does not exist")
    _check_writable_dir("--output", args.output.parent)
    from pe_mjx.export import arena_xml

    xml = arena_xml(args.preset, args.seed)
    # Write a fresh temporary file next to the output, then rename: never a half-written output,
    # never an existing file clobbered by the temporary one.
    try:
        fd, tmp = tempfile.mkstemp(
            dir=args.output.parent, prefix=f".{args.output.name}.", suffix=".tmp"
        )
        try:
            with os.fdopen(fd, "w") as f:
                f.write(xml)
            os.chmod(tmp, 0o644)
            os.replace(tmp, args.output)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as err:
        _fail(f"cannot write {args.output}: {err}")
    print(f"wrote {args.output} (preset {args.preset}, seed {args.seed})")


def run_demo(args: DemoArgs) -> None:
    _check_preset(args.preset)
    _check_seed(args.seed)
    _check_backend(args.backend)
    if args.steps < 1:
        _fail(f"--steps must be >= 1, got {args.steps}")
    from pe_mjx.match import play_scripted_match

    result = play_scripted_match(args.preset, args.seed, args.backend, args.steps)
    for key, value in result.items():
        print(f"{key:>28s}: {value}")


@dataclasses.dataclass(frozen=True)
class ExportArgs:
    """Write one team's policy of a run as a self-contained file: StableHLO through `jax.export`
    (the greedy policy, normaliser and parameters folded in), run by
    pe_mjx/policy/export_loader.py with only jax and numpy, e.g. on a robot's computer (README,
    "Running a policy on robots")."""

    run: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN")]
    """A `pe-mjx train` run directory or a shipped policy's name (mix-20-5-8)."""
    output: Annotated[Path, tyro.conf.arg(aliases=("-o",))] = Path("policy.jaxexport")
    """Where to write the policy file (a zip of policy.stablehlo and meta.json)."""
    team: Literal["pursuer", "evader"] = "pursuer"
    """Which of the run's policies to export."""
    preset: PresetName | None = None
    """Scene whose counts fix the input shapes; smaller scenes are padded by the loader (default:
    the run's own scene; 4-2-2 is the paper's robot setup)."""
    force: bool = False
    """Overwrite an existing output file."""


def run_export(args: ExportArgs) -> None:
    if args.output.is_dir():
        _fail(f"--output: {args.output} is a directory; give the path of the file to write")
    if args.output.exists() and not args.force:
        _fail(f"--output: {args.output} exists; pass --force to overwrite it")
    if not args.output.parent.is_dir():
        _fail(f"--output: directory {args.output.parent} does not exist")
    _check_writable_dir("--output", args.output.parent)
    from pe_mjx.config import get_preset
    from pe_mjx.policy.export import export_policy, write_policy
    from pe_mjx.policy.store import CheckpointError

    config = None if args.preset is None else get_preset(args.preset)
    try:
        program, info = export_policy(args.run, args.team, config)
    except CheckpointError as err:
        _fail(str(err))
    try:
        size = write_policy(args.output, program, info)
    except OSError as err:
        _fail(f"cannot write {args.output}: {err}")
    counts = ", ".join(f"{n} {k}" for k, n in info["counts"].items())
    print(f"wrote {args.output} ({size:,} bytes): the {args.team} policy of {args.run} ({counts})")


@dataclasses.dataclass(frozen=True)
class PlotArgs:
    """Plot a run's learning curves (success against the scripted teams, per-team returns), or a
    replay written by `pe-mjx evaluate` as a top-down trajectory plot (the paper's Fig. 4) or,
    with -o x.gif / x.mp4, as an animation."""

    path: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="RUN|REPLAY.npz")]
    """A `pe-mjx train` run directory, or a trajectory .npz (results/*/trajectories/)."""
    output: Annotated[Path | None, tyro.conf.arg(aliases=("-o",))] = None
    """File to write: .png (default <run>/learning_curve.png or <replay>.png); for a replay
    also .gif or .mp4 (an animation; MP4 needs the video extra)."""
    arena: int = 0
    """Which recorded arena of a replay to draw."""
    fps: int = 10
    """Frames per second of an animation."""


def run_plot(args: PlotArgs) -> None:
    from pe_mjx import plots

    if args.fps < 1:
        _fail(f"--fps must be >= 1, got {args.fps}")
    if args.output is not None and not args.output.parent.is_dir():
        _fail(f"--output: directory {args.output.parent} does not exist")
    if args.path.is_dir():
        if args.output is not None and args.output.suffix.lower() != ".png":
            _fail("--output: learning curves are written as a .png file")
        path, table = plots.learning_curves(args.path, args.output)
        print(table, end="")
        print(f"wrote {path}")
        return
    if not args.path.is_file():
        _fail(f"{args.path}: no such run directory or replay file")
    from pe_mjx.trajectory import TrajectoryError
    from pe_mjx.trajectory import load as load_trajectory

    try:
        traj = load_trajectory(args.path)
    except TrajectoryError as err:
        _fail(str(err))
    out = args.output or args.path.with_suffix(".png")
    if out.suffix.lower() in (".gif", ".mp4"):
        path = plots.animate_trajectory(traj, out, args.arena, args.fps)
    elif out.suffix.lower() == ".png":
        path = plots.plot_trajectory(traj, out, args.arena)
    else:
        _fail(f"--output: a replay is plotted to .png, .gif or .mp4, got {out.name}")
    print(f"wrote {path}")


def run_reproduce(args: ReproduceArgs) -> None:
    from pe_mjx.reproduce import reproduce

    print(f"wrote {reproduce(args)}")


def _one_line(box: str) -> str:
    """tyro's boxed error message as one line (its text without the frame and the help hint)."""
    parts = []
    for line in box.splitlines():
        text = re.sub(r"[│╭╮╰╯─]+|-{3,}", " ", line).strip()
        if not text or text.startswith(("For full helptext", "Usage:", "usage:")):
            continue
        parts.append(text)
    message = re.sub(r"\s+", " ", " ".join(parts)).strip()
    for prefix in ("Value error ", "Parsing error ", "Invalid choice "):
        message = message.removeprefix(prefix)
    message = message.replace("Unrecognized options Unrecognized options:", "unrecognized flags:")
    # "Error parsing experiment.env.arena: invalid config: radius must ..." -> "--env.arena.radius
    # must ...": name the flag.
    found = re.match(r"Error parsing ([\w.]+): invalid config: ([\w.]+) (.*)", message)
    if found:
        path = found.group(1).split(".")[1:]
        field = found.group(2)
        if path and field.startswith(path[-1] + "."):
            path = path[:-1]
        flag = ".".join([*path, field]).replace("_", "-")
        message = f"--{flag} {found.group(3)}"
    return message or "invalid arguments (see --help)"


def _parse(parse: Callable[[], object]) -> object:
    """Runs a tyro parse; its errors become one line `pe-mjx: error: ...` and exit code 2."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            return parse()
    except SystemExit as exit_:
        if exit_.code in (0, None):
            sys.stderr.write(captured.getvalue())
            raise
        _fail(_one_line(captured.getvalue()))
    except ValueError as err:  # a config check that failed while the flags were parsed
        _fail(str(err))
    raise AssertionError("unreachable")


def main(argv: list[str] | None = None) -> None:
    commands = {
        "scene": (SceneArgs, run_scene),
        "demo": (DemoArgs, run_demo),
        "train": (TrainArgs, run_train),
        "view": (ViewArgs, run_view),
        "evaluate": (EvaluateArgs, run_evaluate),
        "export": (ExportArgs, run_export),
        "plot": (PlotArgs, run_plot),
        "reproduce": (ReproduceArgs, run_reproduce),
    }
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv == ["--version"]:
        from importlib.metadata import PackageNotFoundError, version

        try:
            print(f"pe-mjx {version('pe-mjx')}")
        except PackageNotFoundError:
            print("pe-mjx (not installed: no version)")
        return
    subcommands = {name: cls for name, (cls, _) in commands.items()}
    # train and evaluate take every field of their config as a flag, over defaults that
    # --preset, --config (and train's --resume) choose: read those first.
    with_defaults = {
        "train": (TrainArgs, train_defaults),
        "evaluate": (EvaluateArgs, evaluate_defaults),
    }
    if argv[:1] and argv[0] in with_defaults:
        cls, defaults = with_defaults[argv[0]]
        if argv[0] == "train" and not {"-h", "--help"} & set(argv):
            join_group(argv[1:])  # before a --resume's checkpoint is read (orbax asks JAX)
        try:
            default = defaults(argv[1:])
        except ValueError as err:
            _fail(str(err))
        args = _parse(
            lambda: tyro.cli(
                cls,
                args=argv[1:],
                default=default,
                prog=f"pe-mjx {argv[0]}",
                description=cls.__doc__,
            )
        )
    else:
        args = _parse(
            lambda: tyro.extras.subcommand_cli_from_dict(subcommands, args=argv, prog="pe-mjx")
        )
    # Ctrl-C and `kill` stop every command the same way (a KeyboardInterrupt: the viewer shuts
    # its server down, training keeps its last atomic checkpoint), with watchdogs.
    for cls, fn in commands.values():
        if isinstance(args, cls):
            with interrupts.installed():
                try:
                    fn(args)
                except ValueError as err:
                    _fail(str(err))
                except OSError as err:  # a file system failure while working: one line too
                    where = f"{err.filename}: " if err.filename else ""
                    _fail(f"{where}{err.strerror or err}")
                except KeyboardInterrupt:
                    print("pe-mjx: interrupted", file=sys.stderr)
                    raise SystemExit(130) from None
            return


if __name__ == "__main__":
    main()
