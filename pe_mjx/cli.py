"""The `pe-mjx` command line: one entry point, one subcommand per job (typed configs via tyro).

This module parses, dispatches and keeps the error contract (every failure one line `pe-mjx:
error: ...`, exit code 2); train and evaluate live here because their flags' defaults come from
--preset, --config and --resume, read before the parse (each once: a resumed run's saved config
travels in `TrainArgs.saved`). The other subcommands are modules of `pe_mjx.commands`. What a
config can check itself (ranges, choices) it checks in its own `__post_init__`; its `invalid
config: <field> ...` becomes `--<field> ...` here (`_one_line`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import tyro

from pe_mjx import interrupts, outputs, sizes
from pe_mjx.commands.common import check_backend as _check_backend
from pe_mjx.commands.common import check_jax_platforms, check_new_file, never_unencodable, printable
from pe_mjx.commands.common import check_preset as _check_preset
from pe_mjx.commands.common import check_seed as _check_seed
from pe_mjx.commands.common import check_writable_dir as _check_writable_dir
from pe_mjx.commands.common import fail as _fail
from pe_mjx.commands.export import ExportArgs, run_export
from pe_mjx.commands.plot import PlotArgs, run_plot
from pe_mjx.commands.rate import RateArgs, run_rate
from pe_mjx.commands.ship import ShipArgs, run_ship
from pe_mjx.commands.train_summary import training_summary
from pe_mjx.commands.view import ViewArgs, run_view
from pe_mjx.config import PRESETS, EnvConfig, PresetName
from pe_mjx.eval_config import EvalConfig
from pe_mjx.experiment import Backend, ExperimentConfig
from pe_mjx.names import BUILTIN_POLICIES
from pe_mjx.ppo.distributed import DEFAULT_HEARTBEAT_TIMEOUT_S, DEFAULT_JOIN_TIMEOUT_S
from pe_mjx.ppo.distributed import FLAGS as GROUP_SETTINGS
from pe_mjx.reproduce import ReproduceArgs


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
    resume_intact: bool = False
    """With --resume: when the latest checkpoint is damaged, move it (and any other damaged later
    one) to RUN/damaged-checkpoints/ and resume from the latest intact checkpoint."""
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
    saved: tyro.conf.Suppress[ExperimentConfig | None] = None
    """The saved config of --resume's run, read once by `train_defaults` (not a flag)."""
    join_timeout: int = DEFAULT_JOIN_TIMEOUT_S
    """Seconds to wait for the coordinator and the other processes when joining the group; an
    unreachable --coordinator-address is then one error line."""


GROUP_FLAGS = (*GROUP_SETTINGS.values(), "--heartbeat-timeout", "--join-timeout")
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
    if "--resume-intact" in argv and "--resume" not in found:
        _fail("--resume-intact goes with --resume RUN")
    preset = found.get("--preset")
    if preset is not None and preset not in PRESETS:
        _fail(f"--preset: unknown preset {preset!r}; known presets: {', '.join(PRESETS)}")
    if "--resume" in found:
        if "--preset" in found or "--config" in found:
            _fail("--resume continues a run with its saved config; drop --preset/--config")
        from pe_mjx.policy.store import CheckpointError
        from pe_mjx.ppo.checkpoint import resume_intact
        from pe_mjx.ppo.run import saved_config

        try:
            if "--resume-intact" in argv:
                resume_intact(found["--resume"])
            base = saved_config(found["--resume"])
        except CheckpointError as err:
            _fail(f"--resume: {err}")
        return TrainArgs(experiment=base, saved=base)
    if "--config" in found:
        return TrainArgs(experiment=read_config_file(found["--config"], preset))
    return TrainArgs(experiment=default_config(preset or "20-5-8"))


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
            join_timeout_s=numbers.get("--join-timeout", DEFAULT_JOIN_TIMEOUT_S),
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
    from pe_mjx.ppo.run import TrainingError, resume_config, saved_config, train

    config = args.experiment
    sizes.check_training(config)  # an absurd count is one line, before anything allocates
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
            saved = args.saved if args.saved is not None else saved_config(args.resume)
            config = resume_config(args.resume, config, saved)
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
        interrupts.exit_now(f"pe-mjx: error: {printable(str(err))}", 2)
    except ProcessLostError as err:
        # jax's own exit would wait for the lost process (the group's shutdown barrier), then
        # abort: the checkpoints are on disk, end now.
        interrupts.exit_now(f"pe-mjx: error: {printable(str(err))}", 1)
    except KeyboardInterrupt:
        # Everything worth keeping is on disk by now: checkpoints are written with interrupts
        # held back, and `train` closed its loggers while unwinding. The interpreter's own exit
        # would then join every thread orbax, jax or a logger left behind, and one stuck among
        # them hung a Ctrl-C'd run under load (a flaky CI test): end without waiting.
        interrupts.exit_now("pe-mjx: interrupted", 130)
    except (CheckpointError, TrainingError) as err:
        _fail(str(err))
    if is_primary():
        training_summary(out, state, config)


@dataclasses.dataclass(frozen=True)
class EvaluateArgs:
    """Cross-confrontation (paper IV-B to IV-E): every pursuer policy against every evader policy.
    A policy is "scripted", "random", a shipped policy ("mix-20-5-8") or a `pe-mjx train` run
    directory. Writes results.md (the paper's table layout), results.csv, trials.csv,
    results.json, heatmaps and trajectories."""

    evaluation: Annotated[EvalConfig, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=EvalConfig
    )
    """What is played (`pe_mjx.eval_config.EvalConfig`, shared with `pe_mjx.evaluate`): each of
    its fields is a flag of its own."""
    preset: PresetName | None = None
    """Scenario preset (P-E-K) whose scene the env flags start from (default 20-5-8)."""
    config: Path | None = None
    """Read the scene from this JSON or YAML file: an env tree (whole or partial, over the
    preset), an experiment tree or a run's config.json (its env); flags given with it override
    it."""
    progress: bool = True
    """Show a progress bar over each pairing's trials (on a terminal, on stderr)."""
    out: Path = Path("results/latest")
    """Output directory."""
    keep: Path | None = None
    """An earlier evaluation's output directory (--out itself, to add policies to it): its
    pairings of the same two policies, scene, trials, seed and backend are kept rather than
    played again, once one of them has replayed identically (else every pairing is played)."""


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
            env = read_env_file(found["--config"], preset)
        except ValueError as err:
            _fail(str(err))
    else:
        env = PRESETS[preset or "20-5-8"]
    return EvaluateArgs(evaluation=EvalConfig(env=env))


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
    if args.out.exists() and not args.out.is_dir():
        _fail(f"--out: {args.out} is not a directory")
    if args.keep is not None and not (args.keep / "results.json").is_file():
        _fail(f"--keep: {args.keep} holds no results.json of `pe-mjx evaluate`")
    extending = args.keep is not None and args.keep.resolve() == args.out.resolve()
    if not extending and args.out.exists() and any(args.out.glob("results.*")):
        _fail(
            f"--out: {args.out} already holds results; choose another --out (or add policies "
            f"to it with --keep {args.out})"
        )
    _check_writable_dir("--out", args.out)
    from pe_mjx.evaluate import check_policy_specs, run_evaluation

    config = args.evaluation
    check_policy_specs(config)  # before any compile
    config = config.replace(env=_named_scene(config.env), record=config.recorded)
    report = run_evaluation(
        config,
        args.out,
        log=lambda line: print(line, file=sys.stderr, flush=True),  # stdout: the table only
        progress=args.progress,
        keep=args.keep,
    )
    print(report["paths"]["markdown"].read_text())
    print(f"wrote {args.out} in {report['meta']['seconds']:.1f} s", file=sys.stderr)


def run_scene(args: SceneArgs) -> None:
    _check_preset(args.preset)
    _check_seed(args.seed)
    check_new_file("--output", args.output, args.force)
    from pe_mjx.export import arena_xml

    xml = arena_xml(args.preset, args.seed)
    # A temporary beside the output, renamed over it (pe_mjx.outputs): never half-written.
    try:
        outputs.write_file(args.output, xml, force=args.force, flag="--output")
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


def run_reproduce(args: ReproduceArgs) -> None:
    from pe_mjx.reproduce import reproduce

    report = reproduce(args)
    if report is not None:
        print(f"wrote {report}")


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
    else:  # a top-level check of a subcommand's args ("Error parsing ReproduceArgs: --only ...")
        message = _flag_message(re.sub(r"^Error parsing [A-Z]\w*: ", "", message))
    return message or "invalid arguments (see --help)"


def _parse(parse: Callable[[], object], argv: list[str]) -> object:
    """Runs a tyro parse; its errors become one line `pe-mjx: error: ...` and exit code 2."""
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            return parse()
    except SystemExit as exit_:
        if exit_.code in (0, None):
            sys.stderr.write(captured.getvalue())
            raise
        _fail(_missing_value(_one_line(captured.getvalue()), argv))
    except ValueError as err:  # a config check that failed while the flags were parsed
        _fail(_flag_message(str(err)))
    raise AssertionError("unreachable")


def _missing_value(message: str, argv: list[str]) -> str:
    """tyro's "Missing argument Missing value for argument '--suffix'. Expected 1 values." as
    "--suffix needs a value". argparse reads a word that starts with "-" as a flag, not as the
    value before it (`--suffix -s1-3m`); where that happened the line says how to pass it."""
    found = re.fullmatch(
        r"Missing argument Missing value for argument '(-[\w.-]+)'\. Expected (\d+) values?\.",
        message,
    )
    if found is None:
        return message
    flag, count = found.group(1), int(found.group(2))
    said = f"{flag} needs a value" if count == 1 else f"{flag} needs {count} values"
    at = argv.index(flag) if flag in argv else -1
    after = argv[at + 1] if 0 <= at < len(argv) - 1 else ""
    if count == 1 and after.startswith("-") and after not in ("-h", "--help"):
        said += f" ({after} reads as a flag; give it as {flag}={after})"
    return said


def _flag_message(message: str) -> str:
    """A top-level config field's check as its flag's: "invalid config: trials must be ..." ->
    "--trials must be ..." (nested fields come through tyro's box, `_one_line`)."""
    found = re.fullmatch(r"invalid config: ([a-z][a-z_]*) ((?:must|needs) .*)", message)
    if found is None:
        return message
    return f"--{found.group(1).replace('_', '-')} {found.group(2)}"


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
        "ship": (ShipArgs, run_ship),
        "rate": (RateArgs, run_rate),
    }
    argv = sys.argv[1:] if argv is None else list(argv)
    never_unencodable(sys.stdout)
    never_unencodable(sys.stderr)
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
    asks_help = bool({"-h", "--help"} & set(argv))
    if argv[:1] and argv[0] in commands and argv[0] not in ("rate", "plot") and not asks_help:
        if argv[0] == "train":
            join_group(argv[1:])  # before a --resume's checkpoint is read (orbax asks JAX)
        check_jax_platforms()  # after joining: asking JAX for devices first breaks the join
    if argv[:1] and argv[0] in with_defaults:
        cls, defaults = with_defaults[argv[0]]
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
            ),
            argv,
        )
    else:
        args = _parse(
            lambda: tyro.extras.subcommand_cli_from_dict(subcommands, args=argv, prog="pe-mjx"),
            argv,
        )
    # Ctrl-C and `kill` stop every command the same way (a KeyboardInterrupt: the viewer shuts
    # its server down, training keeps its last atomic checkpoint), with watchdogs.
    for cls, fn in commands.values():
        if isinstance(args, cls):
            with interrupts.installed():
                try:
                    fn(args)
                    interrupts.check()  # a Ctrl-C after the last safe point is not lost
                except ValueError as err:
                    _fail(str(err))
                except OSError as err:  # a file system failure while working: one line too
                    where = f"{err.filename}: " if err.filename else ""
                    _fail(f"{where}{err.strerror or err}")
                except KeyboardInterrupt:
                    interrupts.stop()  # one line, exit 130 (without the interpreter's teardown)
            interrupts.finish()  # the pe-mjx process ends here (exit 0, no teardown)
            return


if __name__ == "__main__":
    interrupts.install_for_cli()
    main()
