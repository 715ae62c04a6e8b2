"""The episodes of an evaluation: jitted batches of one pairing's trials (one compile per shape),
the progress bar over them, and the recording of a pairing's first trials as a trajectory."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from pe_mjx import interrupts, trajectory
from pe_mjx.env import PursuitEvasionEnv
from pe_mjx.episodes import play_episodes
from pe_mjx.eval_metrics import PairingResult
from pe_mjx.policy.core import Policy


class Games:
    """Jitted episode batches, one compile per (pursuer shape, evader shape, batch, record): the
    policies' learned state is an argument, so pairings of same-shaped policies share a program
    (compiling took about 15 s of each pairing when every pairing closed over its parameters)."""

    def __init__(self, env: PursuitEvasionEnv, log: Any = None):
        self.env = env
        self.log = log
        """Told "compiling..." before each new compile when no progress bar shows it."""
        self.compiled: dict[tuple, Callable[..., Any]] = {}
        self.shapes_run: set[tuple] = set()

    def _fn(self, p_spec: Policy, e_spec: Policy, record: bool) -> Callable[..., Any]:
        key = (p_spec.shape_key, e_spec.shape_key, record)
        if key not in self.compiled:
            p_apply, e_apply, env = p_spec.apply, e_spec.apply, self.env

            def run(p_vars, e_vars, keys):
                pols = {
                    "pursuer": lambda obs, rng: p_apply(p_vars, obs, rng),
                    "evader": lambda obs, rng: e_apply(e_vars, obs, rng),
                }
                return play_episodes(env, pols, keys, record=record)

            self.compiled[key] = jax.jit(run)
        return self.compiled[key]

    def play(self, p_spec, e_spec, keys, bar=None, title: str = ""):
        """The batched final state of one episode per key, in chunks so that the progress bar
        moves over the trials (chunks of equal size, the last padded: one compile). Only on
        CPU, where a wider batch gains little; an accelerator plays all trials in one batch."""
        fn = self._fn(p_spec, e_spec, False)
        n = len(keys)
        steps = PROGRESS_STEPS if jax.default_backend() == "cpu" else 1
        chunk = -(-n // min(n, steps))
        task = None
        if bar is not None:
            task = bar.add_task(title, total=n)
        finals = []
        for start in range(0, n, chunk):
            interrupts.check()  # a safe point between compiled calls (Ctrl-C)
            part = keys[start : start + chunk]
            if len(part) < chunk:
                part = jnp.concatenate([part, keys[: chunk - len(part)]])
            shape = (p_spec.shape_key, e_spec.shape_key, chunk)
            if shape not in self.shapes_run:
                if bar is not None:
                    bar.update(task, description=f"{title}: compiling...")
                elif self.log is not None:
                    self.log(f"{title}: compiling...")
            self.shapes_run.add(shape)
            final = fn(p_spec.variables, e_spec.variables, part)
            finals.append(final)
            if bar is not None:
                bar.update(task, advance=min(chunk, n - start), description=title)
        if bar is not None:
            bar.remove_task(task)
        return jax.tree.map(lambda *x: jnp.concatenate(x)[:n], *finals)

    def record(self, p_spec, e_spec, keys):
        shape = (p_spec.shape_key, e_spec.shape_key, len(keys), "record")
        if shape not in self.shapes_run and self.log is not None:
            self.log(f"{e_spec.label} vs {p_spec.label}: compiling the recording...")
        self.shapes_run.add(shape)
        fn = self._fn(p_spec, e_spec, True)
        return fn(p_spec.variables, e_spec.variables, keys)


PROGRESS_STEPS = 10
"""On CPU the trials of a pairing run in at most this many equal chunks (one progress step
each); arena i depends on its key alone, so the results are those of one batch."""


@contextlib.contextmanager
def progress_bar(enabled: bool):
    """A rich progress bar on stderr (stdout keeps only the results), or None."""
    if not enabled:
        yield None
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    console = Console(stderr=True)
    if not console.is_terminal:
        yield None
        return
    columns = [
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
    ]
    with Progress(*columns, console=console, transient=True) as bar:
        yield bar


def record_pairing(
    games: Games, p_spec, e_spec, keys, result: PairingResult, out: Path, seed: int
) -> None:
    env = games.env
    final, traj = games.record(p_spec, e_spec, keys)
    # Cut the frames after the longest of the recorded episodes ended.
    length = int(np.max(np.asarray(final.world.step))) + 1
    traj = jax.tree.map(lambda x: np.asarray(x)[:length], traj)
    meta = {
        "pursuer": result.pursuer.label,
        "evader": result.evader.label,
        "pursuer_source": result.pursuer.source,
        "evader_source": result.evader.source,
        "seed": seed,
        "trials": list(range(len(keys))),
    }
    rec = trajectory.from_episodes(env.config, traj, final, meta)
    path = out / "trajectories" / f"pairing-{result.index}.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    trajectory.save(path, rec, overwrite=True)
