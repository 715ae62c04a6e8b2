"""Headless Chromium looking at the viewer, driven by Playwright: what the viewer's browser
tests, its benchmark and its soak (`tools/bench_viewer.py`, `tools/soak_viewer.py`) share.

It lives in the package, beside the viewer it checks, because a tool may import only the
installed package (not a test, not another tool), as the benchmarks' timing code does
(`pe_mjx.bench`). Playwright is imported only when a browser is launched: it comes with the
`dev` extra, and nothing else in `pe_mjx` needs it. `tests/viewer/browser.py` adds the pytest
glue.

Playwright (the ``playwright`` package) drives Debian's ``chromium`` through ``executable_path``:
no browser is downloaded (never ``playwright install``). Chromium renders viser's WebGL in
software with ``--enable-unsafe-swiftshader`` (SPEC 7). This module keeps the small API the tests
and tools were written against:

    with Browser.launch() as browser:
        page = browser.new_page("http://127.0.0.1:8080")
        image = page.screenshot()  # uint8 [H, W, 3]
        page.click_text("Pause")
        page.errors  # console errors and uncaught exceptions of the page, as text
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import io
import os
import re
import shutil
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "chrome")
# Playwright's headless=True adds a plain `--headless` (the new mode since Chromium 132); a later
# switch wins, so the mode is pinned here as SPEC 7 states it.
CHROMIUM_ARGS = (
    "--headless=new",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    # Tabs render at once in the tests and the soak: keep background tabs from being throttled.
    "--disable-background-timer-throttling",
    "--disable-backgrounding-occluded-windows",
    "--disable-renderer-backgrounding",
    "--disable-dev-shm-usage",
)
# Milliseconds: a loaded 2-core machine renders software WebGL slowly.
ACTION_TIMEOUT_MS = 60_000
LIVE_VIEWER = {
    "preset": "4-1-2",
    "backend": "kinematic",
    "pursuers": "scripted",
    "evaders": "random",
    "arenas": 2,
    "speed": 15.0,
}
"""`start_viewer` options of the live viewer the browser tests and `tools/bench_reconnect.py`
look at: small, quick to compile, both teams on screen most of the time."""


class BrowserError(RuntimeError):
    """Chromium is missing or did not start, or the page did not do what was asked in time."""


def find_chromium() -> str | None:
    """Path of a Chromium binary ($CHROMIUM overrides), or None."""
    env = os.environ.get("CHROMIUM")
    if env:
        return env if Path(env).exists() else shutil.which(env)
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


class Browser:
    """One Chromium process (Playwright's) and one browser context holding the tabs."""

    def __init__(self, playwright: Any, browser: Any, width: int, height: int):
        self._playwright = playwright
        self._browser = browser
        self._context = browser.new_context(
            viewport={"width": width, "height": height}, device_scale_factor=1
        )
        self._context.set_default_timeout(ACTION_TIMEOUT_MS)
        self._context.set_default_navigation_timeout(ACTION_TIMEOUT_MS)
        self.pages: list[Page] = []

    @classmethod
    def launch(
        cls, binary: str | None = None, width: int = 1024, height: int = 768, timeout: float = 60.0
    ) -> Browser:
        """Starts headless Chromium (a throw-away profile)."""
        binary = binary or find_chromium()
        if binary is None:
            raise BrowserError("no Chromium found (install Debian's `chromium` or set $CHROMIUM)")
        from playwright.sync_api import Error, sync_playwright

        playwright = sync_playwright().start()
        try:
            browser = playwright.chromium.launch(
                executable_path=binary,
                headless=True,
                args=list(CHROMIUM_ARGS),
                timeout=timeout * 1000,
            )
            return cls(playwright, browser, width, height)
        except Error as err:
            playwright.stop()
            raise BrowserError(f"Chromium did not start: {err.message}") from None

    @property
    def version(self) -> str:
        return self._browser.version

    def new_page(self, url: str, width: int = 1024, height: int = 768) -> Page:
        """Opens `url` in a new tab of `width` x `height` CSS pixels and returns it."""
        page = Page(self, self._context.new_page())
        page.page.set_viewport_size({"width": width, "height": height})
        self.pages.append(page)
        try:
            page.goto(url)
        except BaseException:
            page.close()
            raise
        return page

    def close(self) -> None:
        for step in (self._context.close, self._browser.close, self._playwright.stop):
            with contextlib.suppress(Exception):
                step()
        self.pages.clear()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


CONSOLE_LINES = 200
"""Console messages a `Page` keeps (the latest)."""
CONNECTION_EVENTS = ("Connecting to", "Connected!", "Disconnected!")
"""How viser's websocket worker logs its connection (viser 1.1.1's client): its console lines
reach the page's console, so `Page.connection_log` tells when a tab lost and regained the
server."""


class Page:
    """One browser tab (`page` is Playwright's). `errors` collects, as text, what the page logged
    with console.error, the exceptions it did not catch and a renderer crash, in order; `console`
    keeps the latest console messages of the page and its workers as (seconds since the tab
    opened, text). Playwright hands page events over while one of its calls runs (any method
    here)."""

    def __init__(self, browser: Browser, page: Any):
        self.browser = browser
        self.page = page
        self.closed = False
        self.errors: list[str] = []
        self.console: collections.deque[tuple[float, str]] = collections.deque(maxlen=CONSOLE_LINES)
        self._opened = time.monotonic()
        self._cdp: Any = None
        page.on("console", self._on_console)
        page.on("pageerror", lambda error: self.errors.append(f"pageerror: {error}"))
        page.on("crash", lambda _: self.errors.append("crash: the tab's renderer crashed"))

    def _on_console(self, message: Any) -> None:
        self.console.append((round(time.monotonic() - self._opened, 2), message.text))
        if message.type == "error":
            self.errors.append(f"console.error: {message.text}")

    def connection_log(self) -> list[str]:
        """The tab's websocket events so far ("12.3 s Connected! ws://..."), oldest first."""
        return [
            f"{t} s {text[:80]}"
            for t, text in self.console
            if any(text.startswith(event) for event in CONNECTION_EVENTS)
        ]

    def _error(self, what: str, err: Exception) -> BrowserError:
        message = getattr(err, "message", str(err)).splitlines()[0]
        return BrowserError(f"{what}: {message}")

    def goto(self, url: str) -> None:
        """Loads `url` and waits for its load event."""
        from playwright.sync_api import Error

        try:
            self.page.goto(url, wait_until="load")
        except Error as err:
            raise self._error(f"could not load {url}", err) from None

    def reload(self) -> None:
        from playwright.sync_api import Error

        try:
            self.page.reload(wait_until="load")
        except Error as err:
            raise self._error("could not reload", err) from None

    def evaluate(self, expression: str) -> Any:
        """Evaluates a JS expression in the page and returns its (JSON) value; a promise is
        awaited."""
        from playwright.sync_api import Error

        try:
            return self.page.evaluate(expression)
        except Error as err:
            raise self._error(f"JS error in {expression!r}", err) from None

    def wait_for(self, expression: str, timeout: float = 30.0, interval: float = 0.2) -> Any:
        """Polls a JS expression until it is truthy (an exception counts as false); returns its
        value."""
        from playwright.sync_api import Error

        guarded = f"() => {{ try {{ return ({expression}); }} catch (e) {{ return null; }} }}"
        try:
            handle = self.page.wait_for_function(
                guarded, polling=interval * 1000, timeout=timeout * 1000
            )
            return handle.json_value()
        except Error as err:
            raise self._error(
                f"timed out after {timeout} s waiting for {expression!r}", err
            ) from None

    def screenshot(self) -> np.ndarray:
        """What the tab shows now: uint8 [H, W, 3]."""
        from PIL import Image

        data = self.page.screenshot(type="png")
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))

    def wait_for_image(
        self, predicate: Callable[[np.ndarray], bool], timeout: float = 60.0, interval: float = 0.5
    ) -> np.ndarray:
        """Screenshots until `predicate(image)` holds; returns that image."""
        deadline = time.monotonic() + timeout
        while True:
            image = self.screenshot()
            if predicate(image):
                return image
            if time.monotonic() > deadline:
                raise BrowserError(f"timed out after {timeout} s waiting for the page to render")
            time.sleep(interval)

    def js_heap_mb(self) -> float:
        """The tab's JavaScript heap in use, MB (DevTools' Runtime.getHeapUsage through
        Playwright's CDP session: exact, where performance.memory is rounded)."""
        if self._cdp is None:
            self._cdp = self.page.context.new_cdp_session(self.page)
        return self._cdp.send("Runtime.getHeapUsage")["usedSize"] / 2**20

    def locator(self, text: str, selector: str = "button") -> Any:
        """Playwright's locator of the first visible `selector` element whose text is `text`."""
        exact = re.compile(rf"^\s*{re.escape(text)}\s*$")
        return self.page.locator(selector).filter(has_text=exact, visible=True).first

    def element_center(self, text: str, selector: str = "button") -> tuple[float, float]:
        """Centre (CSS pixels) of the first visible `selector` element whose text is `text`,
        scrolled into view once it is visible and holds still."""
        from playwright.sync_api import Error

        target = self.locator(text, selector)
        try:
            target.scroll_into_view_if_needed()
            box = target.bounding_box()
        except Error as err:
            raise self._error(f"no {selector} {text!r} to be seen", err) from None
        if box is None:
            raise BrowserError(f"the {selector} {text!r} is not displayed")
        return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2

    def click(self, x: float, y: float) -> None:
        """A real left click at (x, y): mouse moved, pressed and released by the browser."""
        self.page.bring_to_front()
        self.page.mouse.click(x, y)

    def click_text(self, text: str, selector: str = "button") -> None:
        """Clicks the button (or `selector` element) labelled `text` with the mouse, once
        Playwright sees it visible, still, enabled and on top at its centre."""
        from playwright.sync_api import Error

        self.page.bring_to_front()
        try:
            self.locator(text, selector).click()
        except Error as err:
            raise self._error(f"could not click the {selector} {text!r}", err) from None

    def close(self) -> None:
        """Closes the tab (the page's websocket to the server goes away with it)."""
        if not self.closed:
            self.closed = True
            with contextlib.suppress(Exception):
                self.page.close()
            if self in self.browser.pages:
                self.browser.pages.remove(self)


# ----------------------------------------------------------------------------- what a page shows


def scene_region(image: np.ndarray, panel_width: int = 340) -> np.ndarray:
    """The 3D view of a viewer screenshot, without the GUI panel (right), the notification
    corner (top left) and the axes gizmo (bottom left), which are blanked to white."""
    out = np.array(image[:, : max(1, image.shape[1] - panel_width)], copy=True)
    out[:170, :330] = 255
    out[-80:, :80] = 255
    return out


def team_pixels(image: np.ndarray) -> dict[str, np.ndarray]:
    """bool masks [H, W] of pixels in the pursuer red and the evader blue of the viewer.

    Thresholds are loose about lighting but exclude the lighter trails, the grey of incapacitated
    agents and the cause markers (see `pe_mjx.viewer.scene`).
    """
    rgb = np.asarray(image, dtype=np.int32)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    red = (r >= 120) & (g <= 110) & (b <= 100) & (r - g >= 60)
    blue = (b >= 120) & (r <= 110) & (b - r >= 60) & (b - g >= 30)
    return {"pursuer": red, "evader": blue}


def team_counts(image: np.ndarray) -> dict[str, int]:
    """Pixels of each team's colour in the 3D view of a viewer screenshot."""
    return {team: int(mask.sum()) for team, mask in team_pixels(scene_region(image)).items()}


def shows_both_teams(image: np.ndarray, minimum: int = 20) -> bool:
    """Whether the 3D view shows at least `minimum` pixels of each team's colour."""
    counts = team_counts(image)
    return counts["pursuer"] >= minimum and counts["evader"] >= minimum


class ConnectionProxy:
    """A localhost TCP proxy in front of a viewer, for what a network does to a tab: `drop()`
    cuts every connection through it (a tab's websocket included; viser's client then
    reconnects), and `handshake_delay` holds each websocket handshake that many seconds before
    it reaches the server (a slow or tunnelled link). Open the page at `url`: viser's client
    derives its websocket address from the page's, so the websocket goes through the proxy too.
    `handshakes` counts the websocket handshakes seen. Runs its own event loop in a thread."""

    def __init__(self, port: int, handshake_delay: float = 0.0):
        self.handshake_delay = handshake_delay
        self.handshakes = 0
        self._target = port
        self._writers: set[Any] = set()
        self._loop = asyncio.new_event_loop()
        started = threading.Event()
        box: dict[str, Any] = {}

        def run() -> None:
            asyncio.set_event_loop(self._loop)
            server = self._loop.run_until_complete(
                asyncio.start_server(self._handle, "127.0.0.1", 0)
            )
            box["port"] = server.sockets[0].getsockname()[1]
            started.set()
            self._loop.run_forever()
            server.close()

        self._thread = threading.Thread(target=run, name="connection-proxy", daemon=True)
        self._thread.start()
        started.wait()
        self.url = f"http://127.0.0.1:{box['port']}/"

    async def _handle(self, client_reader: Any, client_writer: Any) -> None:
        head = await client_reader.read(65536)
        if b"upgrade: websocket" in head.lower():
            self.handshakes += 1
            await asyncio.sleep(self.handshake_delay)
        try:
            server_reader, server_writer = await asyncio.open_connection("127.0.0.1", self._target)
        except OSError:
            client_writer.close()
            return
        self._writers |= {client_writer, server_writer}
        server_writer.write(head)

        async def pipe(reader: Any, writer: Any) -> None:
            with contextlib.suppress(OSError):
                while data := await reader.read(65536):
                    writer.write(data)
                    await writer.drain()
            writer.close()
            self._writers.discard(writer)

        await asyncio.gather(pipe(client_reader, server_writer), pipe(server_reader, client_writer))

    def _cut(self) -> None:
        for writer in tuple(self._writers):
            writer.transport.abort()
        self._writers.clear()

    def drop(self) -> None:
        """Cuts every open connection, as a network outage would."""
        self._loop.call_soon_threadsafe(self._cut)

    def close(self) -> None:
        """Cuts every connection and stops. The loop turns once more after the cut: an aborted
        transport closes its socket only then, and a socket left open would keep its client on
        the server."""

        async def shut() -> None:
            self._cut()
            await asyncio.sleep(0.1)

        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(shut(), self._loop).result(timeout=5)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=5)


__all__ = [
    "LIVE_VIEWER",
    "Browser",
    "BrowserError",
    "ConnectionProxy",
    "Page",
    "find_chromium",
    "scene_region",
    "shows_both_teams",
    "team_counts",
    "team_pixels",
]
