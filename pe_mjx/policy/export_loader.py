"""Runs a policy file written by `pe-mjx export`, with jax and numpy only (copy it anywhere).

This module imports nothing from pe_mjx, flax, brax or the training code, so it can be copied on
its own to a robot's computer that has `jax` (with `flatbuffers`, which `jax.export` needs to
read the file) and `numpy`::

    from export_loader import load
    policy = load("pursuer.jaxexport")
    actions = policy(obs)                 # int32 [A], greedy over the masked logits
    v, omega = policy.commands(obs)       # m/s and rad/s per robot

The file is a zip archive of two members:

* ``policy.stablehlo``: the `jax.export` serialisation (StableHLO bytecode plus its calling
  convention) of ``(own, teammates, opponents, obstacles, teammate_mask, opponent_mask,
  obstacle_mask, action_mask) -> (actions int32 [A], logits float32 [A, n_actions])``: the
  observation normaliser and the network parameters are constants inside it, and the logits of
  masked actions are -1e9;
* ``meta.json``: the format tag and version, the team, the inputs' names, shapes and dtypes, the
  team's action table (the (v, omega) of each action index), the game config and the run it came
  from.

The shapes are fixed when the file is written (a team size, the other team's size, an obstacle
count). Observations with fewer agents or entities are padded up to them with masked entries,
which the networks ignore (padded entities are zeroed and masked out of attention and means), and
the extra rows are dropped from the outputs; more than the exported counts is an error.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import export

FORMAT = "pe-mjx-exported-policy"
VERSION = 1
PROGRAM = "policy.stablehlo"
META = "meta.json"


class ExportedPolicy:
    """A policy read from a `pe-mjx export` file.

    Attributes:
      team: "pursuer" or "evader".
      inputs: [(name, shape, dtype)] in call order, the shapes the file was exported for.
      speeds, turn_rates: float32 [n_actions], the (v, omega) of each action index.
      meta: everything in meta.json (game config, source run, ...).
    """

    def __init__(self, path: str | Path):
        path = Path(path)
        try:
            with zipfile.ZipFile(path) as archive:
                meta = json.loads(archive.read(META))
                program = archive.read(PROGRAM)
        except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as err:
            raise ValueError(f"{path} is not a pe-mjx exported policy: {err}") from None
        if meta.get("format") != FORMAT:
            raise ValueError(f"{path} is not a pe-mjx exported policy (format tag missing)")
        if meta.get("version") != VERSION:
            raise ValueError(
                f"{path} has exported-policy format version {meta.get('version')!r}; this loader "
                f"reads version {VERSION}"
            )
        self.meta = meta
        self.team = meta["team"]
        self.inputs = [(i["name"], tuple(i["shape"]), np.dtype(i["dtype"])) for i in meta["inputs"]]
        self.speeds = np.asarray(meta["action_table"]["v"], np.float32)
        self.turn_rates = np.asarray(meta["action_table"]["omega"], np.float32)
        self._exported = export.deserialize(bytearray(program))
        # One compile per input shape: padding, the program and the slicing fuse into one call.
        self._apply = jax.jit(self._unjitted_apply)

    @property
    def num_agents(self) -> int:
        return self.inputs[0][1][0]

    @property
    def num_actions(self) -> int:
        return len(self.speeds)

    def _padded(self, obs: dict[str, Any]) -> tuple[list[jax.Array], int]:
        args, rows = [], None
        for name, shape, dtype in self.inputs:
            if name not in obs:
                raise ValueError(f"observation has no {name!r} (expected {self.names})")
            x = jnp.asarray(obs[name]).astype(dtype)
            if x.ndim != len(shape) or any(n > m for n, m in zip(x.shape, shape, strict=True)):
                raise ValueError(
                    f"{name} has shape {tuple(x.shape)}; this file was exported for at most "
                    f"{shape} (re-export with a larger scene)"
                )
            rows = x.shape[0] if rows is None else rows
            if x.shape[0] != rows:
                raise ValueError(f"{name} has {x.shape[0]} agents, {self.inputs[0][0]} has {rows}")
            args.append(jnp.pad(x, [(0, m - n) for n, m in zip(x.shape, shape, strict=True)]))
        return args, rows

    @property
    def names(self) -> list[str]:
        return [name for name, _, _ in self.inputs]

    def apply(self, obs: dict[str, Any]) -> tuple[jax.Array, jax.Array]:
        """(actions int32 [A], logits float32 [A, n_actions]) for one team's observation dict of
        one arena (SPEC 2.5 layout, `state.obs[team]`). Jittable."""
        names = set(self.names)
        return self._apply({k: v for k, v in obs.items() if k in names})

    def _unjitted_apply(self, obs: dict[str, Any]) -> tuple[jax.Array, jax.Array]:
        args, rows = self._padded(obs)
        actions, logits = self._exported.call(*args)
        return actions[:rows], logits[:rows]

    def __call__(self, obs: dict[str, Any], rng: Any = None) -> jax.Array:
        """Greedy actions int32 [A]; the signature of pe-mjx policies, `rng` is unused."""
        return self.apply(obs)[0]

    def commands(self, obs: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """(v [A] in m/s, omega [A] in rad/s) of the greedy actions."""
        actions = np.asarray(self(obs))
        return self.speeds[actions], self.turn_rates[actions]


def load(path: str | Path) -> ExportedPolicy:
    """Reads a `pe-mjx export` file; ValueError if it is not one."""
    return ExportedPolicy(path)
