"""How much of the paper's pursuit shaping a local pursuer can see, per scene.

    python experiments/results/pursuit_shaping.py [--arenas 16] \\
        [--out docs/data/pursuit_shaping.json]

The pursuer's shaping term of eq. (3), f_p = 10 / max(d, d_cap), is summed over every active
evader. For freshly drawn arenas of 20-5-8 and of the larger scenes at 24-6-12's density
(`pe_mjx.config.scene_by_counts`, as experiments/results/large_scale.py plays them) this writes
its mean per pursuer at the first state, summed over every evader (the paper's,
`reward.pursuit_nearest = None`) and over each pursuer's k nearest (k = 1, 4): the part a
pursuer reading its k nearest evaders sees. docs/results.md (section 10) quotes it.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from pe_mjx.config import scene_by_counts
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.stages.geometry import geometry
from pe_mjx.stages.rewards import paper_terms

ROOT = Path(__file__).resolve().parents[2]


@dataclasses.dataclass(frozen=True)
class Args:
    arenas: int = 16
    """Arenas drawn per scene (seeds 0..arenas-1)."""
    scenes: tuple[str, ...] = ("20-5-8", "60-15-30", "120-30-60", "240-60-120")
    out: Path = ROOT / "docs" / "data" / "pursuit_shaping.json"


def shaping(name: str, arenas: int) -> dict[str, float]:
    base = scene_by_counts(name)
    env = PursuitEvasionEnv(base, backend="kinematic")
    p, e = base.pursuer.num_agents, base.evader.num_agents
    configs = {
        "all evaders" if k is None else f"{k} nearest": base.replace(
            reward=dataclasses.replace(base.reward, pursuit_nearest=k)
        )
        for k in (None, 4, 1)
    }
    values: dict[str, list[float]] = {label: [] for label in configs}
    for seed in range(arenas):
        state = env.reset(jax.random.PRNGKey(seed))
        world, obstacles = state.world, env.obstacles(state)
        g = geometry(world.pos, world.yaw, obstacles)
        none = jnp.zeros((p, e), bool)
        for label, config in configs.items():
            terms = paper_terms(config, g, world.active, none, obstacles)
            values[label].append(float(np.asarray(terms["pursuer"]["pursuit"]).mean()))
    return {label: round(float(np.mean(v)), 2) for label, v in values.items()}


def main(args: Args) -> None:
    data = {"arenas": args.arenas, "per_pursuer_and_step": {}}
    for name in args.scenes:
        data["per_pursuer_and_step"][name] = shaping(name, args.arenas)
        print(name, data["per_pursuer_and_step"][name])
    args.out.write_text(json.dumps(data, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
