"""What browsers may send the viewer: every GUI value checked on the server before it is applied.

Viser applies a browser's ``GuiUpdateMessage`` as it comes: any property of any GUI element (its
callbacks included), with a loose cast (``int(1e30)``, ``bool("no")``) and no bounds. One forged
message could strip a button's handlers for everyone or store a value that no new connection can
serialise. `GuiGuard` sits in front of viser's handler: a message passes only if it sets the
``value`` of a registered input to a value of the right type, finite and within the input's
current bounds or options; anything else is dropped, reported (`on_reject`) and the sender's widget
is set back to the server's value. The client-to-server messages this app never uses (forms,
uploads, commands, button holds) are not handled at all.

`PolicyAccess` decides which policy paths typed into the GUI may be opened: run directories under
a few roots (the working directory and the shipped policies by default), with one answer for
every path outside them, so that the page never tells which paths exist on the server.
"""

from __future__ import annotations

import contextlib
import dataclasses
import ipaddress
import math
import socket
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from pe_mjx.policy.shipped import resolve_run

MAX_TEXT = 1024
"""Characters of a text input at most."""
MAX_ARENAS = 64
"""Arenas at most (GUI and `pe-mjx view --arenas`)."""
MAX_COUNT = 1000
"""Pursuers, evaders or obstacles at most in the GUI's scene controls."""
SEED_MAX = 2**32 - 1
"""Largest seed (`jax.random.key` keeps 32 bits of it)."""

SHIPPED_POLICIES = Path(__file__).resolve().parents[1] / "assets" / "policies"
"""The shipped policies (package data; a checkout's assets/policies links to them)."""


class GuiValueError(ValueError):
    """A GUI value that a browser sent and the server refused."""


@dataclasses.dataclass(frozen=True)
class Rule:
    """What one input accepts.

    kind: "button" (a click: True), "bool", "int", "float", "choice" (one of the handle's
    options) or "text". Numbers must also lie within the handle's current min and max (and
    within `minimum`/`maximum` where given); ints must be whole numbers.
    """

    kind: str
    minimum: float | None = None
    maximum: float | None = None
    max_length: int = MAX_TEXT


def _bounds(handle: Any, rule: Rule) -> tuple[float, float]:
    lo, hi = -math.inf, math.inf
    for value in (getattr(handle, "min", None), rule.minimum):
        if value is not None:
            lo = max(lo, float(value))
    for value in (getattr(handle, "max", None), rule.maximum):
        if value is not None:
            hi = min(hi, float(value))
    return lo, hi


def check_address(host: str, port: int) -> bool:
    """Checks that the viewer can listen on `host`:`port` before viser tries (viser retries the
    next port forever on any bind error, so a bad host would hang).

    Returns:
      Whether every address `host` resolves to is a loopback address (this machine only).
    Raises:
      ValueError: a port outside 0..65535, a host that does not resolve or is not an address of
        this machine.
    """
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ValueError(f"--port must be in 0..65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as err:
        reason = getattr(err, "strerror", None) or str(err)
        raise ValueError(f"--host {host!r} does not resolve ({reason})") from None
    local = True
    for family, kind, proto, _, address in infos:
        try:
            with socket.socket(family, kind, proto) as sock:
                sock.bind((address[0], 0, *address[2:]))
        except OSError as err:
            raise ValueError(
                f"--host {host!r}: cannot listen on {address[0]} ({err.strerror or err})"
            ) from None
        local = local and ipaddress.ip_address(address[0].split("%")[0]).is_loopback
    return local


def _number(text: float) -> str:
    return str(int(text)) if float(text).is_integer() else f"{text:g}"


def check_value(handle: Any, rule: Rule, value: Any) -> Any:
    """The value, normalised to the handle's type; GuiValueError if the rule refuses it."""
    kind = rule.kind
    if kind in ("button", "bool"):
        if not isinstance(value, bool) or (kind == "button" and value is not True):
            raise GuiValueError("expected true or false" if kind == "bool" else "not a click")
        return value
    if kind in ("int", "float"):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise GuiValueError(f"expected a number, got {type(value).__name__}")
        if not math.isfinite(value):
            raise GuiValueError("expected a finite number")
        lo, hi = _bounds(handle, rule)
        if not lo <= value <= hi:
            raise GuiValueError(f"must be in [{_number(lo)}, {_number(hi)}]")
        if kind == "int":
            if not float(value).is_integer():
                raise GuiValueError("expected a whole number")
            return int(value)
        return float(value)
    if kind == "choice":
        options = tuple(getattr(handle, "options", ()))
        if not isinstance(value, str) or value not in options:
            raise GuiValueError(f"expected one of {', '.join(options)}")
        return value
    if kind == "text":
        if not isinstance(value, str):
            raise GuiValueError(f"expected text, got {type(value).__name__}")
        if len(value) > rule.max_length:
            raise GuiValueError(f"longer than {rule.max_length} characters")
        if any(not ch.isprintable() for ch in value):
            raise GuiValueError("holds control characters")
        return value
    raise AssertionError(f"unknown rule kind {kind!r}")


def _preview(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


# Client-to-server messages that this app never uses; viser's handlers for them are removed.
_UNUSED = (
    "GuiButtonHoldMessage",
    "GuiFormSubmitMessage",
    "GuiFormDirtyMessage",
    "FileTransferStartUpload",
    "FileTransferPart",
    "CommandTriggerMessage",
)


class GuiGuard:
    """Validates every ``GuiUpdateMessage`` before viser applies it (see the module docstring).

    Args:
      server: the `viser.ViserServer`.
      on_reject: called with one line (label, value, reason) for every refused message, on
        viser's event-loop thread.
    """

    def __init__(self, server: Any, on_reject: Callable[[str], None]):
        from viser import _messages

        self._server = server
        self._on_reject = on_reject
        self._rules: dict[str, tuple[Any, Rule]] = {}
        self._update_message = _messages.GuiUpdateMessage
        self.rejected = 0
        # Viser has no public hook for incoming messages: swap its GUI handler for ours.
        gui = server.gui
        self._websock = gui._websock_interface
        self._apply = gui._handle_gui_updates
        self._websock.unregister_handler(self._update_message, self._apply)
        self._websock.register_handler(self._update_message, self._handle)
        for name in _UNUSED:
            cls = getattr(_messages, name, None)
            if cls is not None:
                with contextlib.suppress(AssertionError, KeyError):
                    self._websock.unregister_handler(cls)

    def add(self, handle: Any, rule: Rule) -> Any:
        """Accepts updates of `handle` under `rule`; returns the handle."""
        self._rules[handle._impl.uuid] = (handle, rule)
        return handle

    def add_all(self, pairs: Iterable[tuple[Any, Rule]]) -> None:
        for handle, rule in pairs:
            self.add(handle, rule)

    async def _handle(self, client_id: int, message: Any) -> None:
        uuid = getattr(message, "uuid", None)
        entry = self._rules.get(uuid) if isinstance(uuid, str) else None
        updates = getattr(message, "updates", None)
        label = "an unknown GUI element" if entry is None else repr(entry[0].label)
        try:
            if entry is None:
                raise GuiValueError("not an input of this viewer")
            if not isinstance(updates, dict) or set(updates) != {"value"}:
                keys = sorted(map(str, updates)) if isinstance(updates, dict) else updates
                raise GuiValueError(f"only a value may be set, got {_preview(keys)}")
            handle, rule = entry
            value = check_value(handle, rule, updates["value"])
        except GuiValueError as err:
            self.rejected += 1
            if isinstance(updates, dict) and "value" in updates:
                what = f"{label} = {_preview(updates['value'])}"
            else:
                what = f"an update of {label}"
            self._on_reject(f"refused {what} from a browser: {err}")
            if entry is not None:
                self._restore(client_id, entry[0])
            return
        await self._apply(client_id, self._update_message(uuid=uuid, updates={"value": value}))

    def _restore(self, client_id: int, handle: Any) -> None:
        """Sets the sender's widget back to the server's value."""
        client = self._server.get_clients().get(client_id)
        if client is None or handle._impl.is_button:
            return
        message = self._update_message(uuid=handle._impl.uuid, updates={"value": handle.value})
        with contextlib.suppress(Exception):
            client._websock_connection.queue_message(message)


@dataclasses.dataclass(frozen=True)
class PolicyAccess:
    """Which policy directories a GUI may open: any directory under one of `roots` (symlinks
    resolved), plus the `extra` paths given when the viewer started."""

    roots: tuple[Path, ...]
    extra: tuple[Path, ...] = ()

    @classmethod
    def default(cls, roots: Iterable[str | Path] | None = None) -> PolicyAccess:
        """The given roots, or the working directory and the shipped policies."""
        chosen = [Path.cwd(), SHIPPED_POLICIES] if roots is None else list(roots)
        return cls(roots=tuple(Path(r).expanduser().resolve() for r in chosen))

    def allowing(self, *paths: str | Path) -> PolicyAccess:
        """Also allows these paths (the policies given on the command line)."""
        extra = tuple(Path(p).expanduser().resolve() for p in paths)
        return dataclasses.replace(self, extra=self.extra + extra)

    def allows(self, spec: str) -> bool:
        try:
            path = resolve_run(spec).resolve()
        except (OSError, RuntimeError, ValueError):
            return False
        if path in self.extra:
            return True
        return any(path.is_relative_to(root) for root in self.roots) and path.is_dir()

    def describe(self) -> str:
        """The allowed roots as the page may show them (relative to the working directory)."""
        cwd = Path.cwd().resolve()
        names = []
        for root in self.roots:
            if root == cwd:
                names.append("the working directory")
            elif root.is_relative_to(cwd):
                names.append(str(root.relative_to(cwd)))
            else:
                names.append(root.name or str(root))
        return ", ".join(names)


__all__ = [
    "MAX_ARENAS",
    "SEED_MAX",
    "GuiGuard",
    "GuiValueError",
    "PolicyAccess",
    "Rule",
    "check_address",
    "check_value",
]
