"""Training on several processes (several machines, or one process per GPU) with jax.distributed.

A group is N processes that each run the same `pe-mjx train` command with the same flags, told
where the coordinator listens (process 0 serves it), how many they are and which one each is:

    pe-mjx train ... --coordinator-address HOST:PORT --num-processes N --process-id I

or the environment variables `JAX_COORDINATOR_ADDRESS`, `JAX_NUM_PROCESSES`, `JAX_PROCESS_ID`
(flags win). `initialize` joins the group before JAX touches a device; from then on
`jax.devices()` lists every process's devices, and the trainer's mesh shards the env batch over
all of them (`pe_mjx.ppo.train`): each process steps its share of the arenas, gradients are
all-reduced, parameters stay replicated. On CPUs the collectives are gloo's (TCP).

What each process does in a run (`pe_mjx.ppo.run`): all of them compute and all write their
shards of a checkpoint (orbax's multi-host save; the run directory must be on a file system every
process sees); process 0 alone takes the run's lock and writes `config.json`, TensorBoard logs,
W&B and the progress bar. A checkpoint restores on any process count (`--resume` with another
N, or with one process).

When a process dies, the others' next collective fails ("connection closed by peer"), or, when
they wait at a checkpoint's barrier, the barrier fails once the coordinator has missed the dead
process's heartbeats for `heartbeat_timeout_s` (`--heartbeat-timeout`): they stop with
`ProcessLostError`, and the command line ends them at once with one line. In the second case
the coordinator also tells every process that the group failed, and jax's error-polling thread
then ends the process with a fatal log: whichever comes first ends it, the one line or jax's
abort (jax's recoverable tasks, which would leave only the line, end each process without
waiting for the others at shutdown, and the coordinator's host then vanishes under the rest).
Either way the last checkpoint is intact (orbax renames a step into place only when every
process finished writing it).

Joining fails fast: a process other than 0 first waits for the coordinator's port to accept a
connection, at most `join_timeout_s` (`--join-timeout`, default `DEFAULT_JOIN_TIMEOUT_S`), and
an address where nothing listens is a `ValueError` naming it (`pe-mjx train` prints it as its one
line). jax itself, when the group does not form within its `initialization_timeout`, ends the
process with a fatal log and a C++ stack trace; so while `jax.distributed.initialize` waits (the
coordinator reachable, but not every process joining), a watchdog ends the process at the join
timeout with one line instead (`JOIN_EXIT_CODE`), before jax's own deadline.

Before the first collective of a program the processes meet at `barrier` (the coordination
service's, with a long timeout): gloo's first collective gives up on a process that is more
than 30 s late, which a process still compiling on a busy machine can be.
"""

from __future__ import annotations

import dataclasses
import os
import socket
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

ENV_VARS = {
    "coordinator_address": "JAX_COORDINATOR_ADDRESS",
    "num_processes": "JAX_NUM_PROCESSES",
    "process_id": "JAX_PROCESS_ID",
}
"""The environment variables a group's settings are read from when no flag gives them."""
FLAGS = {
    "coordinator_address": "--coordinator-address",
    "num_processes": "--num-processes",
    "process_id": "--process-id",
}
"""The `pe-mjx train` flags of a group's settings (the command line reads them first)."""
DEFAULT_HEARTBEAT_TIMEOUT_S = 100
"""jax's default: seconds without a heartbeat after which the coordinator declares a process
lost (and jax ends the group)."""
DEFAULT_JOIN_TIMEOUT_S = 60
"""Seconds a process waits for the coordinator and for the group to form (`--join-timeout`)."""
MAX_TIMEOUT_S = 7 * 24 * 3600
"""The longest --join-timeout and --heartbeat-timeout (a week): 10**23 s waited for ever."""
JOIN_EXIT_CODE = 2
"""The exit code of a process whose group did not form within the join timeout."""
_JAX_MARGIN_S = 30  # jax's own deadline comes this much after the watchdog's


class ProcessLostError(RuntimeError):
    """Another process of the group died (its collective failed): this one cannot go on."""


@dataclasses.dataclass(frozen=True)
class Group:
    """The settings of one process of a group (`jax.distributed.initialize`)."""

    coordinator_address: str
    """HOST:PORT where process 0 serves the coordinator and the others reach it."""
    num_processes: int
    process_id: int
    heartbeat_timeout_s: int = DEFAULT_HEARTBEAT_TIMEOUT_S
    join_timeout_s: int = DEFAULT_JOIN_TIMEOUT_S
    """Seconds to wait for the coordinator and the other processes when joining."""


def _source(field: str, given: object) -> str:
    return FLAGS[field] if given is not None else ENV_VARS[field]


def group_from(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    heartbeat_timeout_s: int = DEFAULT_HEARTBEAT_TIMEOUT_S,
    environ: Mapping[str, str] | None = None,
    join_timeout_s: int = DEFAULT_JOIN_TIMEOUT_S,
) -> Group | None:
    """The group given by the flags, else the environment variables; None for a lone process
    (neither gives any setting). A missing or bad setting is a `ValueError` naming the flag or
    the variable."""
    environ = os.environ if environ is None else environ
    given = {
        "coordinator_address": coordinator_address,
        "num_processes": num_processes,
        "process_id": process_id,
    }
    values: dict[str, object] = {}
    for field, value in given.items():
        if value is None and environ.get(ENV_VARS[field], "").strip():
            value = environ[ENV_VARS[field]].strip()
            if field != "coordinator_address":
                try:
                    value = int(value)
                except ValueError:
                    raise ValueError(
                        f"{ENV_VARS[field]} must be an integer, got {environ[ENV_VARS[field]]!r}"
                    ) from None
        values[field] = value
    if all(v is None for v in values.values()):
        return None
    missing = [f for f, v in values.items() if v is None]
    if missing:
        names = ", ".join(f"{FLAGS[f]} (or {ENV_VARS[f]})" for f in missing)
        raise ValueError(f"training on several processes also needs {names}")
    address = str(values["coordinator_address"])
    host, _, port = address.rpartition(":")
    # isascii: "²" passes isdigit but not int() (a message that named no flag).
    if not host or not (port.isascii() and port.isdigit()) or not 0 < int(port) < 65536:
        where = _source("coordinator_address", coordinator_address)
        raise ValueError(f"{where} must be HOST:PORT (e.g. 10.0.0.1:1234), got {address!r}")
    n, i = int(values["num_processes"]), int(values["process_id"])  # type: ignore[arg-type]
    if n < 1:
        raise ValueError(f"{_source('num_processes', num_processes)} must be >= 1, got {n}")
    if not 0 <= i < n:
        raise ValueError(
            f"{_source('process_id', process_id)} must be in [0, {n}) for {n} processes, got {i}"
        )
    if not 1 <= heartbeat_timeout_s <= MAX_TIMEOUT_S:
        raise ValueError(
            f"--heartbeat-timeout must be in 1..{MAX_TIMEOUT_S:,} s, got {heartbeat_timeout_s}"
        )
    if not 1 <= join_timeout_s <= MAX_TIMEOUT_S:
        raise ValueError(f"--join-timeout must be in 1..{MAX_TIMEOUT_S:,} s, got {join_timeout_s}")
    return Group(address, n, i, heartbeat_timeout_s, join_timeout_s)


def _joining(group: Group) -> str:
    return (
        f"--coordinator-address: process {group.process_id} of {group.num_processes} cannot "
        f"join the group at {group.coordinator_address}"
    )


def wait_for_coordinator(group: Group, timeout_s: float) -> None:
    """Waits until the coordinator's port accepts a TCP connection (process 0 may start a little
    later than the others); `ValueError` naming the address when it does not within
    `timeout_s`."""
    host, _, port = group.coordinator_address.rpartition(":")
    host = host.strip("[]")  # [::1]:1234
    deadline = time.monotonic() + timeout_s
    reason = "no answer"
    while True:
        left = deadline - time.monotonic()
        try:
            with socket.create_connection((host, int(port)), timeout=max(0.1, min(left, 5.0))):
                return
        except OSError as err:  # refused, unreachable, unknown host, timed out
            reason = err.strerror or str(err) or type(err).__name__
        if time.monotonic() + 0.5 >= deadline:
            raise ValueError(
                f"no coordinator answers at {group.coordinator_address} within {timeout_s:g} s "
                f"({reason}); start process 0 first, check the address, or raise --join-timeout"
            )
        time.sleep(0.5)


def initialize(group: Group) -> None:
    """Joins the group (blocks until every process has joined, `jax.distributed.initialize`).
    Must run before anything asks JAX for a device.

    Within `group.join_timeout_s`: an unreachable coordinator is a `ValueError` (naming the
    address); a group that does not form in time (the coordinator reachable, some process
    missing) ends this process with one line on stderr and `JOIN_EXIT_CODE`, since jax's
    blocked join cannot be interrupted and would otherwise abort with a C++ stack trace."""
    import jax

    start = time.monotonic()
    if group.process_id != 0:
        wait_for_coordinator(group, group.join_timeout_s)
    left = max(1.0, group.join_timeout_s - (time.monotonic() - start))
    # CPU processes need a collectives implementation to reach each other (GPUs use NCCL).
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    watchdog = threading.Timer(left, _join_timed_out, args=(group,))
    watchdog.daemon = True
    watchdog.start()
    try:
        jax.distributed.initialize(
            coordinator_address=group.coordinator_address,
            num_processes=group.num_processes,
            process_id=group.process_id,
            heartbeat_timeout_seconds=group.heartbeat_timeout_s,
            initialization_timeout=int(left) + _JAX_MARGIN_S,
        )
    finally:
        watchdog.cancel()


def _join_timed_out(group: Group) -> None:
    """The join watchdog: one line, and the process ends (jax's join cannot be interrupted)."""
    print(
        f"pe-mjx: error: {_joining(group)}: the group did not form within "
        f"{group.join_timeout_s} s (--join-timeout): not every one of the {group.num_processes} "
        f"processes joined",
        file=sys.stderr,
        flush=True,
    )
    os._exit(JOIN_EXIT_CODE)


BARRIER_TIMEOUT_S = 3600
"""How long a process waits at `barrier` for the others (compiling a large scene on a loaded
CPU takes minutes)."""


def barrier(name: str, timeout_s: int = BARRIER_TIMEOUT_S) -> None:
    """Waits until every process of the group has reached `name` (a no-op for a lone process).

    The coordination service's barrier, not a collective: the first gloo collective gives up
    when the other processes are more than 30 s late ("Gloo context initialization failed:
    GetKeyValue() timed out"), and a process that compiles on a busy machine can be later than
    that. So the trainer compiles each program ahead of time and meets the others here before
    running it. Each name may be used once per run."""
    import jax

    if jax.process_count() == 1:
        return
    from orbax.checkpoint import multihost

    multihost.get_barrier_sync_fn()(key=name, timeout_ms=timeout_s * 1000)


def is_primary() -> bool:
    """Whether this process writes the run's files (process 0; a lone process too)."""
    import jax

    return jax.process_index() == 0


_LOST_MARKERS = (
    "connection closed by peer",
    "gloo",
    "coordination service",
    "coordinationservice",
    "heartbeat",
    "task is set to error",
)


def is_lost_process_error(err: BaseException) -> bool:
    """Whether `err`, or an error it was raised from, is a collective or a barrier that failed
    because another process went away. orbax reports a barrier of a checkpoint save that failed
    that way as a plain `TimeoutError` raised from the coordination service's error."""
    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        text = str(err).lower()
        if any(marker in text for marker in _LOST_MARKERS):
            return True
        err = err.__cause__ or err.__context__
    return False


@contextmanager
def lost_process_guard() -> Iterator[None]:
    """In a group, turns a collective that failed because a process died into
    `ProcessLostError` (one line for the user); anything else passes through."""
    import jax

    try:
        yield
    except Exception as err:
        if jax.process_count() > 1 and is_lost_process_error(err):
            raise ProcessLostError(
                f"process {jax.process_index()} of {jax.process_count()}: another process of "
                f"the group stopped ({' '.join(str(err).split())[:160]}); stopping this one. "
                f"The last checkpoint is intact: resume with --resume on any number of processes"
            ) from None
        raise


__all__ = [
    "BARRIER_TIMEOUT_S",
    "DEFAULT_HEARTBEAT_TIMEOUT_S",
    "DEFAULT_JOIN_TIMEOUT_S",
    "ENV_VARS",
    "FLAGS",
    "JOIN_EXIT_CODE",
    "Group",
    "ProcessLostError",
    "barrier",
    "group_from",
    "initialize",
    "is_lost_process_error",
    "is_primary",
    "lost_process_guard",
    "wait_for_coordinator",
]
