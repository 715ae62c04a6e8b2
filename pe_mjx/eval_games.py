"""The episodes of an evaluation: jitted batches of one pairing's trials (one compile per shape),
the progress bar over them, and the recording of a pairing's first trials as a trajectory."""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import threading
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


@dataclasses.dataclass
class _Program:
    fn: Callable[..., Any]
    batches_run: set[int] = dataclasses.field(default_factory=set)
    """Batch sizes this program was called with: each compiled once."""


PROGRAMS_KEPT = 32
"""Compiled episode programs kept per process (least recently used dropped first)."""

_programs: collections.OrderedDict[tuple, _Program] = collections.OrderedDict()
_programs_lock = threading.Lock()


def clear_programs() -> None:
    """Forgets every compiled episode program of this process (the next evaluation compiles)."""
    with _programs_lock:
        _programs.clear()


class Games:
    """Jitted episode batches, one compile per (scene, backend, pursuer shape, evader shape,
    record, batch): the policies' learned state is an argument, so pairings of same-shaped
    policies share a program (compiling took about 15 s of each pairing when every pairing
    closed over its parameters). The programs outlive one evaluation: a later `evaluate()` of
    the same scene in the same process (a sweep, a notebook, `keep=`) reuses them, up to
    `PROGRAMS_KEPT` of them."""

    def __init__(self, env: PursuitEvasionEnv, log: Any = None):
        self.env = env
        self.log = log
        """Told "compiling..." before each new compile when no progress bar shows it."""

    def _program(self, p_spec: Policy, e_spec: Policy, record: bool) -> _Program:
        # A policy's shape_key fixes its program for a given scene; builtin policies are built
        # from the scene's config, so the config (a frozen dataclass) is part of the key.
        key = (self.env.config, self.env.backend, p_spec.shape_key, e_spec.shape_key, record)
        with _programs_lock:
            program = _programs.get(key)
            if program is None:
                program = _programs[key] = _Program(self._jit(p_spec, e_spec, record))
                while len(_programs) > PROGRAMS_KEPT:
                    _programs.popitem(last=False)
            _programs.move_to_end(key)
        return program

    def _jit(self, p_spec: Policy, e_spec: Policy, record: bool) -> Callable[..., Any]:
        p_apply, e_apply, env = p_spec.apply, e_spec.apply, self.env

        def run(p_vars, e_vars, keys):
            pols = {
                "pursuer": lambda obs, rng: p_apply(p_vars, obs, rng),
                "evader": lambda obs, rng: e_apply(e_vars, obs, rng),
            }
            return play_episodes(env, pols, keys, record=record)

        return jax.jit(run)

    def play(self, p_spec, e_spec, keys, bar=None, title: str = ""):
        """The batched final state of one episode per key, in chunks so that the progress bar
        moves over the trials (chunks of equal size, the last padded: one compile). Only on
        CPU, where a wider batch gains little; an accelerator plays all trials in one batch."""
        program = self._program(p_spec, e_spec, False)
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
            if chunk not in program.batches_run:
                if bar is not None:
                    bar.update(task, description=f"{title}: compiling...")
                elif self.log is not None:
                    self.log(f"{title}: compiling...")
            program.batches_run.add(chunk)
            final = program.fn(p_spec.variables, e_spec.variables, part)
            finals.append(final)
            if bar is not None:
                bar.update(task, advance=min(chunk, n - start), description=title)
        if bar is not None:
            bar.remove_task(task)
        return jax.tree.map(lambda *x: jnp.concatenate(x)[:n], *finals)

    def record(self, p_spec, e_spec, keys):
        program = self._program(p_spec, e_spec, True)
        if len(keys) not in program.batches_run and self.log is not None:
            self.log(f"{e_spec.label} vs {p_spec.label}: compiling the recording...")
        program.batches_run.add(len(keys))
        return program.fn(p_spec.variables, e_spec.variables, keys)


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
