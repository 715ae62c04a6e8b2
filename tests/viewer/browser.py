"""A minimal headless-Chromium driver over the DevTools protocol (browser tests, docs screenshots).

It talks to Debian's ``chromium`` through one websocket (the ``websockets`` package, which viser
already depends on), so nothing is downloaded and no WebDriver is needed. Chromium renders viser's
WebGL in software with ``--enable-unsafe-swiftshader`` (SPEC 7).

    with Browser.launch() as browser:
        page = browser.new_page("http://127.0.0.1:8080")
        image = page.screenshot()  # uint8 [H, W, 3]
        page.click_text("Pause")
"""

from __future__ import annotations

import base64
import contextlib
import io
import itertools
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "chrome")
CHROMIUM_FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-dev-shm-usage",
    # Two tabs render at once in the tests: keep background tabs from being throttled.
    "--disable-background-timer-throttling",
    "--disable-backgrounding-occluded-windows",
    "--disable-renderer-backgrounding",
)


class BrowserError(RuntimeError):
    """Chromium is missing, did not start, or a DevTools command failed."""


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
    """One Chromium process and its browser-level DevTools connection."""

    def __init__(
        self, process: subprocess.Popen, ws_url: str, profile: tempfile.TemporaryDirectory
    ):
        from websockets.sync.client import connect

        self._process = process
        self._profile = profile
        self._ws = connect(ws_url, max_size=256 * 1024 * 1024, open_timeout=30)
        self._ids = itertools.count(1)
        self.pages: list[Page] = []

    @classmethod
    def launch(
        cls, binary: str | None = None, width: int = 1024, height: int = 768, timeout: float = 60.0
    ) -> Browser:
        """Starts headless Chromium with a throw-away profile."""
        binary = binary or find_chromium()
        if binary is None:
            raise BrowserError("no Chromium found (install Debian's `chromium` or set $CHROMIUM)")
        profile = tempfile.TemporaryDirectory(prefix="pe-mjx-chromium-")
        args = [
            binary,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={profile.name}",
            f"--window-size={width},{height}",
            "--remote-debugging-port=0",
            "about:blank",
        ]
        process = subprocess.Popen(
            args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, bufsize=1
        )
        # Chromium prints "DevTools listening on ws://..." on stderr once it is ready.
        deadline = time.monotonic() + timeout
        lines: list[str] = []
        assert process.stderr is not None
        while time.monotonic() < deadline:
            line = process.stderr.readline()
            if not line:
                if process.poll() is not None:
                    break
                continue
            lines.append(line)
            match = re.search(r"DevTools listening on (ws://\S+)", line)
            if match:
                # Keep draining stderr so that Chromium never blocks on a full pipe.
                _drain(process.stderr)
                return cls(process, match.group(1), profile)
        process.kill()
        profile.cleanup()
        raise BrowserError("Chromium did not start:\n" + "".join(lines[-20:]))

    # ------------------------------------------------------------------ protocol

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        """Sends one command and waits for its result (events are dropped)."""
        msg_id = next(self._ids)
        message: dict[str, Any] = {"id": msg_id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        self._ws.send(json.dumps(message))
        while True:
            reply = json.loads(self._ws.recv(timeout=120))
            if reply.get("id") != msg_id:
                continue
            if "error" in reply:
                raise BrowserError(f"{method} failed: {reply['error']}")
            return reply.get("result", {})

    # ------------------------------------------------------------------ pages

    def new_page(self, url: str, width: int = 1024, height: int = 768) -> Page:
        """Opens `url` in a new window and returns its page."""
        target = self.send("Target.createTarget", {"url": "about:blank", "newWindow": True})
        target_id = target["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target_id, "flatten": True})
        page = Page(self, target_id, session["sessionId"])
        page.send("Page.enable")
        page.send("Runtime.enable")
        page.send(
            "Emulation.setDeviceMetricsOverride",
            {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
        )
        page.goto(url)
        self.pages.append(page)
        return page

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.send("Browser.close")
        with contextlib.suppress(Exception):
            self._ws.close()
        try:
            self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait(timeout=10)
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _drain(stream: Any) -> None:
    import threading

    def run() -> None:
        for _ in stream:
            pass

    threading.Thread(target=run, daemon=True).start()


class Page:
    """One browser tab."""

    def __init__(self, browser: Browser, target_id: str, session: str):
        self.browser = browser
        self.target_id = target_id
        self.session = session
        self.closed = False

    def send(self, method: str, params: dict | None = None) -> dict:
        return self.browser.send(method, params, self.session)

    def goto(self, url: str) -> None:
        self.send("Page.navigate", {"url": url})
        self.wait_for("document.readyState === 'complete'", timeout=60)

    def reload(self) -> None:
        self.send("Page.reload", {"ignoreCache": False})
        time.sleep(0.2)
        self.wait_for("document.readyState === 'complete'", timeout=60)

    def evaluate(self, expression: str) -> Any:
        """Evaluates JS in the page and returns its (JSON) value."""
        result = self.send(
            "Runtime.evaluate",
            {"expression": expression, "returnByValue": True, "awaitPromise": True},
        )
        if "exceptionDetails" in result:
            raise BrowserError(f"JS error in {expression!r}: {result['exceptionDetails']}")
        return result.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float = 30.0, interval: float = 0.2) -> Any:
        """Polls a JS expression until it is truthy; returns its value."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                value = self.evaluate(expression)
            except BrowserError:
                value = None
            if value:
                return value
            if time.monotonic() > deadline:
                raise BrowserError(f"timed out after {timeout} s waiting for {expression!r}")
            time.sleep(interval)

    def screenshot(self) -> np.ndarray:
        """What the tab shows now: uint8 [H, W, 3]."""
        from PIL import Image

        data = self.send("Page.captureScreenshot", {"format": "png"})["data"]
        image = Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB")
        return np.asarray(image)

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

    def element_center(self, text: str, selector: str = "button") -> tuple[float, float]:
        """Centre (CSS pixels) of the first visible `selector` element whose text is `text`.

        Waits until the element has stopped moving (two reads 0.1 s apart agree) and is the
        topmost element at its centre, so a click lands on it even while the page re-renders.
        """
        js = f"""
        (() => {{
          for (const el of document.querySelectorAll({json.dumps(selector)})) {{
            if (el.innerText.trim() !== {json.dumps(text)}) continue;
            el.scrollIntoView({{block: "center", behavior: "instant"}});
            const r = el.getBoundingClientRect();
            if (r.width <= 0 || r.height <= 0) continue;
            const x = r.x + r.width / 2, y = r.y + r.height / 2;
            const hit = document.elementFromPoint(x, y);
            return [x, y, hit !== null && (hit === el || el.contains(hit))];
          }}
          return null;
        }})()
        """
        deadline = time.monotonic() + 30.0
        last = None
        while True:
            found = self.wait_for(js, timeout=max(1.0, deadline - time.monotonic()))
            center = (float(found[0]), float(found[1]))
            if found[2] and center == last:
                return center
            if time.monotonic() > deadline:
                raise BrowserError(f"the {selector} {text!r} never held still and on top")
            last = center
            time.sleep(0.1)

    def click(self, x: float, y: float) -> None:
        """A real left click at (x, y): mouse moved, pressed and released by the browser."""
        base = {"x": x, "y": y, "button": "left", "clickCount": 1}
        self.send("Page.bringToFront")
        self.send("Input.dispatchMouseEvent", {"type": "mouseMoved", "x": x, "y": y})
        self.send("Input.dispatchMouseEvent", {"type": "mousePressed", **base})
        self.send("Input.dispatchMouseEvent", {"type": "mouseReleased", **base})

    def click_text(self, text: str, selector: str = "button") -> None:
        """Clicks the button (or `selector` element) labelled `text`."""
        self.click(*self.element_center(text, selector))

    def close(self) -> None:
        """Closes the tab (the page's websocket to the server goes away with it)."""
        if not self.closed:
            self.browser.send("Target.closeTarget", {"targetId": self.target_id})
            self.closed = True
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


def require_chromium() -> str:
    """For tests: the Chromium path; skips without one, but fails under CI=true (the browser
    tests must run in CI)."""
    import pytest

    path = find_chromium()
    if path is None:
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(
                "CI is set but no Chromium was found: the viewer's browser tests must run "
                "(.ci/run installs Debian's chromium; or set $CHROMIUM)"
            )
        pytest.skip("no Chromium found (apt-get install chromium) for the viewer's browser tests")
    return path


__all__ = [
    "Browser",
    "BrowserError",
    "Page",
    "find_chromium",
    "require_chromium",
    "scene_region",
    "team_pixels",
]
