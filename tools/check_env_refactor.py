"""Records the env's trajectories and lowered step, or compares them against a recording.

    .venv/bin/python tools/check_env_refactor.py record /tmp/env_ref
    .venv/bin/python tools/check_env_refactor.py compare /tmp/env_ref

For the presets 20-5-8 and 4-2-2 on both backends: 16 arenas reset from a fixed key, then 200
steps of `AutoResetWrapper.step_batch` (so finished arenas are redrawn: placement is exercised too)
with actions a seeded `jax.random` policy samples uniformly among those the action mask allows.
Every leaf of every State (the first and the 200 after each step: world, physics, obs, reward,
done, metrics, info) goes to `<dir>/<preset>_<backend>.npz`, the State's tree structure and the
text of `jax.jit(env.step).lower(state, actions)` (one arena) beside it. `compare` recomputes all
of that with the code as it is now and reports, per leaf, whether it is bit-identical
(`np.array_equal`, NaNs equal), then whether the structures are identical (up to the object
addresses MJX's static fields print) and the lowered texts too, or else the same operations in
another order (sorted lines with SSA names blanked).
Exit status 0 only if every leaf and every structure matches (the lowered text is reported, not
required).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx.env import AutoResetWrapper, make
from pe_mjx.names import TEAMS

PRESETS = ("20-5-8", "4-2-2")
BACKENDS = ("kinematic", "mjx")
ARENAS = 16
STEPS = 200


def masked_uniform(key: jax.Array, obs: dict) -> dict[str, jax.Array]:
    """One action per agent, uniform among those its action mask allows. [B, A] per team."""
    keys = jax.random.split(key, len(TEAMS))
    return {
        t: jax.random.categorical(k, jnp.where(obs[t]["action_mask"], 0.0, -jnp.inf))
        for k, t in zip(keys, TEAMS, strict=True)
    }


def record(preset: str, backend: str) -> tuple[dict[str, np.ndarray], str, str]:
    """(leaves by path, tree structure, lowered step text) for one preset and backend."""
    env = make(preset, backend=backend)
    wrapped = AutoResetWrapper(env)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), ARENAS))

    @jax.jit
    def rollout(states, key):
        def body(carry, key):
            new = wrapped.step_batch(carry, masked_uniform(key, carry.obs))
            return new, new

        _, trajectory = jax.lax.scan(body, states, jax.random.split(key, STEPS))
        return trajectory

    trajectory = rollout(states, jax.random.key(1))
    both = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), states, trajectory)
    leaves = {
        jax.tree_util.keystr(path): np.asarray(
            jax.random.key_data(leaf)
            if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key)
            else leaf
        )
        for path, leaf in jax.tree_util.tree_flatten_with_path(both)[0]
    }
    one = jax.tree.map(lambda x: x[0], states)
    actions = {t: jnp.zeros(env.config.team(t).num_agents, jnp.int32) for t in TEAMS}
    lowered = jax.jit(env.step).lower(one, actions).as_text()
    return leaves, str(jax.tree.structure(states)), lowered


def normalise_tree(text: str) -> str:
    """The tree structure's text without the object addresses some of MJX's static fields print."""
    return re.sub(r"0x[0-9a-f]+", "0x?", text)


def op_lines(text: str) -> list[str]:
    """The lowered program's lines with SSA names and function-name suffixes blanked, sorted: the
    same multiset of operations and constants, whatever the order in which they were created."""
    lines = (re.sub(r"%[\w#.]+", "%", line).strip() for line in text.splitlines())
    return sorted(re.sub(r"@(\w+?)_\d+\b", r"@\1", line) for line in lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", choices=("record", "compare"))
    parser.add_argument("dir", type=Path)
    args = parser.parse_args(argv)
    args.dir.mkdir(parents=True, exist_ok=True)
    ok = True
    for preset in PRESETS:
        for backend in BACKENDS:
            name = f"{preset}_{backend}"
            leaves, structure, lowered = record(preset, backend)
            if args.mode == "record":
                np.savez_compressed(args.dir / f"{name}.npz", **leaves)
                (args.dir / f"{name}.tree.txt").write_text(structure)
                (args.dir / f"{name}.lowered.txt").write_text(lowered)
                print(f"{name}: recorded {len(leaves)} leaves")
                continue
            with np.load(args.dir / f"{name}.npz") as ref:
                ref_leaves = {k: ref[k] for k in ref.files}
            same_keys = set(ref_leaves) == set(leaves)
            differ = [
                k
                for k in ref_leaves
                if k not in leaves
                or ref_leaves[k].dtype != leaves[k].dtype
                or not np.array_equal(ref_leaves[k], leaves[k], equal_nan=True)
            ]
            ref_tree = (args.dir / f"{name}.tree.txt").read_text()
            same_tree = normalise_tree(ref_tree) == normalise_tree(structure)
            ref_lowered = (args.dir / f"{name}.lowered.txt").read_text()
            same_lowered = ref_lowered == lowered
            same_ops = op_lines(ref_lowered) == op_lines(lowered)
            ok &= same_keys and not differ and same_tree
            print(
                f"{name}: {len(leaves)} leaves ({len(ref_leaves)} recorded), "
                f"{len(ref_leaves) - len(differ)} bit-identical, differ: {differ or 'none'}; "
                f"same leaf paths: {same_keys}; same tree structure: {same_tree}; "
                f"same lowered jit(env.step) text: {same_lowered}, the same operations up to "
                f"order and SSA names: {same_ops}"
            )
    if args.mode == "compare":
        print("IDENTICAL" if ok else "DIFFERENT")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
