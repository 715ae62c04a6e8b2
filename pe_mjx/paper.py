"""The paper's experiments as a registry (like the presets) and its published Tables II-VI.

`paper_runs()` gives the twelve co-evolutions of paper IV-B (four encoders at three scales, each
training a pursuer and an evader policy with the same encoder, 10 million env steps); `PAPER`
holds the paper's numbers that `pe-mjx reproduce` sets beside ours, and `TABLES` which
scene and training scales each table uses. `SETTINGS` holds what the paper says of each training
setting, in its own words, and `hyperparameters` sets a config's settings beside them.
"""

from __future__ import annotations

from pe_mjx.experiment import ExperimentConfig, default_config
from pe_mjx.names import ENCODERS

SCALES = ("16-4-4", "20-5-8", "24-6-12")
ENV_STEPS = 10_000_000


def paper_experiment(
    encoder: str, preset: str, env_steps: int = ENV_STEPS, backend: str = "mjx", seed: int = 0
) -> ExperimentConfig:
    """One co-evolution of the paper: both teams learn with `encoder` in `preset`."""
    return default_config(preset).override(
        {
            "pursuer.network.encoder": encoder,
            "evader.network.encoder": encoder,
            "env_steps": env_steps,
            "backend": backend,
            "seed": seed,
        }
    )


def paper_runs(
    env_steps: int = ENV_STEPS, backend: str = "mjx", seed: int = 0
) -> dict[str, ExperimentConfig]:
    """Run name ("<encoder>-<preset>") -> its config, for the twelve co-evolutions."""
    return {
        f"{encoder}-{preset}": paper_experiment(encoder, preset, env_steps, backend, seed)
        for preset in SCALES
        for encoder in ENCODERS
    }


# The paper's tables: (evader method, pursuer method) -> (success, travel, pursuit cost,
# per-evader cost).
PAPER = {
    "II": {
        ("mlp", "birnn"): (0.995, 3.948, 4.32, 1.085),
        ("mlp", "mean"): (0.998, 2.954, 3.89, 0.975),
        ("mlp", "mix"): (1.000, 3.527, 4.35, 1.088),
        ("birnn", "mlp"): (0.565, 19.805, 7.05, 3.119),
        ("birnn", "mean"): (0.470, 18.477, 3.71, 1.973),
        ("birnn", "mix"): (0.863, 20.694, 5.18, 1.501),
        ("mean", "mlp"): (0.193, 22.096, 5.32, 6.909),
        ("mean", "birnn"): (0.648, 29.808, 5.26, 2.031),
        ("mean", "mix"): (0.748, 27.832, 4.42, 1.478),
        ("mix", "mlp"): (0.638, 16.641, 8.56, 3.357),
        ("mix", "birnn"): (0.733, 27.303, 5.44, 1.857),
        ("mix", "mean"): (0.503, 19.276, 3.52, 1.751),
    },
    "III": {
        ("mlp", "birnn"): (0.998, 2.743, 6.30, 1.263),
        ("mlp", "mean"): (0.998, 3.068, 5.26, 1.054),
        ("mlp", "mix"): (1.000, 3.637, 4.96, 0.992),
        ("birnn", "mlp"): (0.708, 14.526, 8.34, 2.356),
        ("birnn", "mean"): (1.000, 9.690, 5.68, 1.136),
        ("birnn", "mix"): (0.992, 12.271, 5.38, 1.085),
        ("mean", "mlp"): (0.440, 17.513, 7.31, 3.323),
        ("mean", "birnn"): (0.760, 21.614, 7.61, 2.003),
        ("mean", "mix"): (0.932, 20.138, 5.56, 1.193),
        ("mix", "mlp"): (0.542, 15.306, 9.15, 3.376),
        ("mix", "birnn"): (0.802, 20.432, 9.12, 2.274),
        ("mix", "mean"): (0.932, 21.375, 6.11, 1.311),
    },
    "IV": {
        ("mlp", "birnn"): (0.995, 3.190, 6.72, 1.126),
        ("mlp", "mean"): (1.000, 2.779, 6.16, 1.027),
        ("mlp", "mix"): (1.000, 2.570, 5.93, 0.988),
        ("birnn", "mlp"): (0.867, 6.727, 11.50, 2.211),
        ("birnn", "mean"): (1.000, 5.725, 6.68, 1.113),
        ("birnn", "mix"): (1.000, 4.191, 5.96, 0.993),
        ("mean", "mlp"): (0.378, 7.939, 8.20, 3.616),
        ("mean", "birnn"): (0.943, 14.928, 8.20, 1.449),
        ("mean", "mix"): (1.000, 7.745, 6.49, 1.082),
        ("mix", "mlp"): (0.502, 7.365, 11.05, 3.669),
        ("mix", "birnn"): (0.912, 16.275, 8.59, 1.570),
        ("mix", "mean"): (0.985, 14.509, 8.05, 1.362),
    },
    "V": {
        ("mlp", "birnn"): (0.998, 3.482, 4.86, 1.218),
        ("mlp", "mean"): (1.000, 3.116, 3.94, 0.985),
        ("mlp", "mix"): (1.000, 3.003, 3.74, 0.935),
        ("birnn", "mean"): (0.835, 20.949, 4.39, 1.314),
        ("birnn", "mix"): (0.915, 19.335, 4.04, 1.104),
        ("mean", "birnn"): (0.390, 27.899, 3.59, 2.301),
        ("mean", "mix"): (0.868, 22.598, 3.71, 1.069),
        ("mix", "birnn"): (0.788, 21.943, 6.52, 2.070),
        ("mix", "mean"): (0.893, 22.985, 4.53, 1.269),
    },
    "VI": {
        ("mlp", "birnn"): (0.998, 3.263, 7.92, 1.322),
        ("mlp", "mean"): (1.000, 2.899, 6.24, 1.040),
        ("mlp", "mix"): (0.988, 6.881, 5.79, 0.976),
        ("birnn", "mean"): (1.000, 7.523, 7.08, 1.180),
        ("birnn", "mix"): (0.997, 13.058, 6.36, 1.064),
        ("mean", "birnn"): (0.823, 15.803, 10.83, 2.192),
        ("mean", "mix"): (0.940, 20.449, 6.78, 1.202),
        ("mix", "birnn"): (0.738, 18.743, 11.04, 2.492),
        ("mix", "mean"): (0.900, 20.796, 8.12, 1.504),
    },
}
# Table -> (test scene, scale the pursuers were trained at, scale the evaders were trained at).
TABLES = {
    "II": ("16-4-4", "16-4-4", "16-4-4"),
    "III": ("20-5-8", "20-5-8", "20-5-8"),
    "IV": ("24-6-12", "24-6-12", "24-6-12"),
    "V": ("16-4-4", "20-5-8", "16-4-4"),
    "VI": ("24-6-12", "20-5-8", "24-6-12"),
}


NOT_STATED = "not stated"
# What the paper says of each training setting: its value (or NOT_STATED) and the words it says
# it in (quoted; its equations and Table I's rows transcribed), or None where it says nothing of it.
SETTINGS = {
    "algorithm": ("IPPO, one shared policy per team", "we utilize the parameter-sharing technique"),
    "network": (NOT_STATED, None),
    "learning_rate": (NOT_STATED, None),
    "ppo": (NOT_STATED, None),
    "gamma": (NOT_STATED, "γ ∈ (0,1] is a discount factor"),
    "reward_scale": (NOT_STATED, None),
    "pursuit_scale": ("10", "f_p = 10 / max(d_op, d_cap)"),
    "capture": (NOT_STATED, "r_s is the reward for successful capture"),
    "reward_constants": (NOT_STATED, "d_danger is a constant"),
    "evader_reward": ("f_c terms and r_e only", "if e_j is not in a collision or captured"),
    "mix_queries": (
        "every entity's state gives a query",
        "each agent's original state is transformed into query, key, and value components",
    ),
    "backend": ("no simulator named", "Timestep 0.2 s"),
    "episode": ("0.2 s steps, 200 s episodes", "Max Iteration Time Per Episode 200 s"),
    "budget": ("10M time steps", "By conducting training for 10 million time steps"),
    "seeds": (NOT_STATED, None),
    "evaluation": (
        "100 trials per pairing, no seed, no intervals",
        "We perform 100 trials for each comparison",
    ),
    "per_evader_cost": ("n' / m' in the text", "It is calculated by dividing n' by m'"),
    "mlp_other_scenes": (
        "left out of Tables V, VI",
        "the policy using MLP fails to adapt to the scale change",
    ),
}


def says(key: str) -> str:
    """The paper's value of setting `key` with the words it comes from, as a table cell."""
    value, words = SETTINGS[key]
    return value if words is None else f'{value} ("{words}")'


def learning_rate(config: ExperimentConfig, team: str) -> float:
    """The Adam step size `team` trains with: its own, else `ppo.learning_rate`."""
    rate = config.team(team).learning_rate
    return config.ppo.learning_rate if rate is None else rate


def step_size(x: float) -> str:
    """A step size as the code and the notes write it: 3e-3 (docs/results.md's number check,
    tests/test_results_doc.py, reads decimals only; the rows of `hyperparameters` are checked
    against the config by tests/experiments/test_recipe.py)."""
    mantissa, exponent = f"{x:.0e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _num(x: float) -> str:
    return f"{x:g}"


def hyperparameters(config: ExperimentConfig, env_steps: int) -> list[dict]:
    """Rows (setting, pursuers, evaders, paper): the training settings of `config` for a budget of
    `env_steps` beside what the paper says of each (`SETTINGS`), "same" where both teams share
    one. docs/results.md's recipe gives them for every co-evolution of Tables II-VI."""
    ppo, reward = config.ppo, config.env.reward
    net = {team: config.team(team).network for team in ("pursuer", "evader")}  # in that order
    iteration = ppo.num_envs * ppo.unroll_length
    same = "same"
    rows = [
        ("Algorithm", "IPPO, one parameter set per team", same, says("algorithm")),
        (
            "Encoder width / MIX heads; policy and value heads",
            *(f"{n.width} / {n.num_heads}; 2 x {n.hidden}" for n in net.values()),
            says("network"),
        ),
        (
            "Adam step size",
            step_size(learning_rate(config, "pursuer")),
            step_size(learning_rate(config, "evader")),
            says("learning_rate"),
        ),
        ("Step-size schedule", f"{ppo.lr_schedule} to 0 over the budget", same, says("ppo")),
        (
            "Arenas x steps per iteration; epochs x minibatches",
            f"{ppo.num_envs} x {ppo.unroll_length} ({iteration:,} env steps); "
            f"{ppo.update_epochs} x {ppo.num_minibatches}",
            same,
            says("ppo"),
        ),
        (
            "Discount γ / GAE λ",
            f"{_num(ppo.gamma)} / {_num(ppo.gae_lambda)}",
            same,
            says("gamma"),
        ),
        (
            "Clip / entropy / value / gradient norm",
            f"{_num(ppo.clip_epsilon)} / {_num(ppo.entropy_coef)} / {_num(ppo.value_coef)} / "
            f"{_num(ppo.max_grad_norm)}",
            same,
            says("ppo"),
        ),
        (
            "Reward scale before GAE",
            _num(config.pursuer.reward_scale),
            _num(config.evader.reward_scale),
            says("reward_scale"),
        ),
        (
            "Rewards",
            f"r_c {_num(reward.collision)}, d_danger {_num(reward.danger_distance)} m, f_p = "
            f"{_num(reward.pursuit_scale)} / max(d, {_num(reward.capture_distance)} m), "
            f"r_s {_num(reward.capture)}",
            f"r_c {_num(reward.collision)}, d_danger {_num(reward.danger_distance)} m, "
            f"r_e {_num(reward.evader_alive)}, flee {_num(reward.evader_flee)} per m",
            f"f_p's {says('pursuit_scale')}; the other constants {NOT_STATED}",
        ),
        ("Budget", f"{env_steps:,} env steps", same, says("budget")),
        (
            "Episode",
            f"{config.env.max_steps} steps of {_num(config.env.control_dt)} s",
            same,
            says("episode"),
        ),
    ]
    keys = ("setting", "pursuers", "evaders", "paper")
    return [dict(zip(keys, row, strict=True)) for row in rows]
