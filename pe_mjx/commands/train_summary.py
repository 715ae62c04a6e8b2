"""What `pe-mjx train` prints when a run ends: what it reached and the commands to look at it."""

from __future__ import annotations

from pathlib import Path

from pe_mjx.config import PRESETS, EnvConfig
from pe_mjx.experiment import ExperimentConfig


def training_summary(out: Path, state, config: ExperimentConfig) -> None:
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
    preset = config.preset in PRESETS and same_scene(config.env, PRESETS[config.preset])
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


def same_scene(a: EnvConfig, b: EnvConfig) -> bool:
    """Whether two games have the same arena, teams and timing (their rewards may differ: the
    training defaults add the evaders' flee shaping to a preset's)."""
    return a.replace(reward=b.reward) == b
