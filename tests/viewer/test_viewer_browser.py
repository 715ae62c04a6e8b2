"""The viewer in a real headless Chromium: what a person would see and do.

Every test opens the page, looks at screenshots (team colours, robots moving or not) and acts
through the browser (real mouse clicks on the GUI's buttons). Server-side handles are only used to
set up a state or to read what the server did.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import viser
from PIL import Image

from pe_mjx.viewer import start_viewer
from tests.viewer.browser import BrowserError, ConnectionProxy, shows_both_teams, team_counts
from tests.viewer.viewer_helpers import (
    ForgedClient,
    gui_uuid,
    robots_mask,
    wait_until,
)

RENDER_TIMEOUT = 90.0


def open_viewer(browser, viewer, url: str | None = None):
    """Opens `viewer` (at `url`, its own by default) in a new tab, brought to the front
    (viser's client retries a dropped websocket only while `document.hasFocus()`; headless
    Chromium reports the focus on every tab, checked 2026-12-06, so this matters for a headed
    browser only), and waits for the page to hold the viewer's GUI (the legend: a page that
    never connected shows viser's bare world axes, whose red and blue would pass for both
    teams) and then a frame with both teams. A timeout says what the page showed (the team
    pixels of its last screenshot, its text) and what the server saw (its clients, the frames
    it streamed), which tell apart a page cut off from the server and one that draws late."""
    page = browser.new_page(url or viewer.url)
    page.page.bring_to_front()
    try:
        page.wait_for("document.body.innerText.includes('incapacitated')", timeout=RENDER_TIMEOUT)
        image = page.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
    except BrowserError as err:
        counts = team_counts(page.screenshot())
        text = " ".join(str(page.evaluate("document.body.innerText")).split())[:300]
        raise AssertionError(
            f"{err}; team pixels {counts}; server: {viewer.num_clients()} clients, "
            f"{viewer.frames_streamed} frames streamed; page text: {text!r}"
        ) from None
    return page, image


def click_until(page, text: str, done, what: str, tries: int = 3) -> None:
    """Clicks an idempotent button (Play, Pause) until `done()`; a loaded 2-core machine can
    drop a click while the page re-renders."""
    for attempt in range(tries):
        page.click_text(text)
        try:
            wait_until(done, timeout=10, what=what)
            return
        except AssertionError:
            if attempt == tries - 1:
                raise


def wait_for_text(page, text: str, timeout: float, what: str) -> None:
    """Waits until `text` is part of what the page shows.

    The page polls itself (Playwright's wait_for_function), so a busy renderer costs no round
    trip per look; the tab is brought to the front first (see `open_viewer`)."""
    page.page.bring_to_front()
    try:
        page.wait_for(f"document.body.innerText.includes({json.dumps(text)})", timeout=timeout)
    except BrowserError as err:
        raise AssertionError(f"timed out after {timeout} s waiting for {what}: {err}") from None


def set_playing(viewer, playing: bool) -> None:
    if playing:
        viewer.play()
    else:
        viewer.pause()


def moved(page, seconds: float = 1.5) -> int:
    """Pixels of robot colour that changed between two screenshots `seconds` apart."""
    before = robots_mask(page.screenshot())
    time.sleep(seconds)
    return int(np.sum(before ^ robots_mask(page.screenshot())))


MOVE_TIMEOUT = 30.0


def assert_moves(page, viewer, what: str, pixels: int = 50, timeout: float = MOVE_TIMEOUT) -> None:
    """Asserts that the page shows robots moving: more than `pixels` robot pixels change between
    two screenshots 1.5 s apart, looked for again until `timeout`.

    One look is not enough: a finished episode holds its last frame 1.5 s, and on the 2-core CI
    machine under the suite's load a page once showed no change in three looks over about 6 s
    (2026-12-06, `test_robots_move_while_playing_and_stop_when_paused_by_click`). A failure says
    what each side did meanwhile: the pixels of every look, the frames the server streamed,
    whether it played, its clients and errors; the tab's team pixels, its websocket events
    (viser's worker logs them) and its text. Frames streamed with the tab connected and nothing
    drawn is a page that does not render; no frames is a server that stopped; a "Disconnected!"
    with no "Connected!" after it is a tab cut off from the server."""
    looks = []
    frames = viewer.frames_streamed
    start = time.monotonic()
    while time.monotonic() - start < timeout:
        looks.append(moved(page))
        if looks[-1] > pixels:
            return
    try:
        text = " ".join(str(page.evaluate("document.body.innerText")).split())[:200]
    except BrowserError as err:
        text = f"unreadable: {err}"
    raise AssertionError(
        f"{what}: robot pixels changed {looks} in {len(looks)} looks over "
        f"{time.monotonic() - start:.0f} s; server: {viewer.frames_streamed - frames} frames "
        f"streamed, playing {viewer.playing}, {viewer.num_clients()} clients, errors "
        f"{viewer.errors[-2:]}; tab: team pixels {team_counts(page.screenshot())}, websocket "
        f"{page.connection_log()[-4:]}, text {text!r}"
    )


WEBGL_RENDERER = """(() => {
  const gl = document.createElement("canvas").getContext("webgl2");
  if (!gl) return null;
  const info = gl.getExtension("WEBGL_debug_renderer_info");
  return gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER);
})()"""


def test_chromium_renders_webgl_in_software_and_reports_page_errors(browser):
    """WebGL 2 on SwiftShader (the flags of SPEC 7); console errors and uncaught exceptions of a
    page are collected in `page.errors` (the soak counts them)."""
    page = browser.new_page(
        "data:text/html,<button>Go</button><script>console.error('logged');"
        "setTimeout(() => { throw new Error('uncaught'); }, 0)</script>"
    )
    try:
        renderer = page.evaluate(WEBGL_RENDERER)
        assert renderer is not None and "SwiftShader" in renderer, renderer
        page.wait_for("document.readyState === 'complete'")
        # Page events reach Python while a driver call runs: evaluate() lets them in.
        wait_until(lambda: page.evaluate("true") and len(page.errors) >= 2, timeout=10)
        assert page.errors == ["console.error: logged", "pageerror: uncaught"]
        assert page.element_center("Go")[0] > 0
    finally:
        page.close()


def test_page_shows_both_teams(browser, live_viewer, tmp_path):
    page, image = open_viewer(browser, live_viewer)
    try:
        counts = team_counts(image)
        assert counts["pursuer"] >= 20 and counts["evader"] >= 20, counts
        Image.fromarray(image).save(tmp_path / "viewer.png")
        text = page.evaluate("document.body.innerText")
        assert "4-1-2" in text and "Pause" in text and "captured" in text
    finally:
        page.close()


def test_robots_move_while_playing_and_stop_when_paused_by_click(browser, live_viewer):
    set_playing(live_viewer, True)
    page, _ = open_viewer(browser, live_viewer)
    try:
        assert_moves(page, live_viewer, "robots did not move while playing")
        # A real mouse click in the browser.
        click_until(page, "Pause", lambda: not live_viewer.playing, "the Pause click")
        frames = live_viewer.frames_streamed
        # Frames sent before the pause may still be drawn: on a loaded machine the page lagged
        # more than the 0.5 s once allowed here (48 pixels moved). Once it has settled, nothing
        # may move, and the server sends nothing more.
        wait_until(lambda: moved(page, seconds=0.5) <= 10, timeout=20, what="a still page")
        changed = moved(page)
        assert changed <= 10, f"{changed} robot pixels changed while paused"
        # A still page fails the moving check, which says why: the server sent nothing, and the
        # tab is connected.
        why = r"0 frames streamed, playing False.*websocket \[.*Connected! ws://"
        with pytest.raises(AssertionError, match=why):
            assert_moves(page, live_viewer, "paused", timeout=3)
        assert live_viewer.frames_streamed == frames
        click_until(page, "Play", lambda: live_viewer.playing, "the Play click")
        assert_moves(page, live_viewer, "robots did not move again after Play")
    finally:
        page.close()


def test_step_button_advances_one_step(browser, live_viewer):
    set_playing(live_viewer, True)  # paused, both evaders may be down: no blue to wait for
    page, _ = open_viewer(browser, live_viewer)
    try:
        set_playing(live_viewer, False)
        time.sleep(0.3)
        before = live_viewer.call(lambda: live_viewer.source.run.episode_steps)
        page.click_text("Step")
        wait_until(
            lambda: live_viewer.call(lambda: live_viewer.source.run.episode_steps) != before,
            timeout=10,
            what="the Step click",
        )
        time.sleep(0.3)
        after = live_viewer.call(lambda: live_viewer.source.run.episode_steps)
        # One step, or a fresh episode when the step landed on a finished one.
        assert after in (before + 1, 0)
        assert not live_viewer.playing
    finally:
        set_playing(live_viewer, True)
        page.close()


def test_two_tabs_then_one_closes_and_one_reloads(browser, live_viewer):
    set_playing(live_viewer, True)
    first, _ = open_viewer(browser, live_viewer)
    second, _ = open_viewer(browser, live_viewer)
    try:
        wait_until(lambda: live_viewer.num_clients() == 2, timeout=20, what="two clients")
        assert_moves(first, live_viewer, "the first tab does not play")
        assert_moves(second, live_viewer, "the second tab does not play")
        second.close()
        wait_until(lambda: live_viewer.num_clients() == 1, timeout=20, what="the tab to leave")
        assert live_viewer.running
        assert_moves(first, live_viewer, "the remaining tab stopped updating")
        first.reload()
        first.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
        wait_until(lambda: live_viewer.num_clients() == 1, timeout=20, what="the reloaded tab")
        assert_moves(first, live_viewer, "the reloaded tab does not play")
    finally:
        first.close()
        second.close()
    # A tab closing never stops the server: a new one still gets the scene.
    third, _ = open_viewer(browser, live_viewer)
    third.close()


def test_a_tab_whose_connection_drops_reconnects_and_plays_on(browser, live_viewer):
    """A network outage cuts the tab's websocket (a proxy between the two drops it): viser's
    client connects again, the server sends it the scene again, and the page plays on."""
    set_playing(live_viewer, True)
    proxy = ConnectionProxy(live_viewer.port)
    page = None
    try:
        page, _ = open_viewer(browser, live_viewer, proxy.url)
        wait_until(lambda: live_viewer.num_clients() == 1, timeout=20, what="the tab")
        before = set(live_viewer.server.get_clients())
        proxy.drop()
        # The server names each connection anew: a new client is the tab back.
        wait_until(
            lambda: set(live_viewer.server.get_clients()) - before,
            timeout=60,
            what="the tab back (a new connection)",
        )
        page.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
        assert_moves(page, live_viewer, "the page does not play after reconnecting")
    finally:
        if page is not None:
            page.close()
        proxy.close()


def test_policy_paths_outside_the_roots_are_refused_alike_in_the_page(browser, live_viewer, capfd):
    """A missing path, an existing system directory and a relative escape get the same error
    (the page never tells which paths exist on the server); the server keeps running."""
    set_playing(live_viewer, True)
    page, _ = open_viewer(browser, live_viewer)
    messages = []
    try:
        for spec in ("/no/such/run", "/etc", "../../../../.."):
            errors = len(live_viewer.errors)
            live_viewer.gui.pursuer_policy.value = spec
            page.click_text("Load policies")
            wait_until(lambda n=errors: len(live_viewer.errors) > n, timeout=30, what="the error")
            message = live_viewer.errors[-1]
            assert f"'{spec}'" in message, message
            messages.append(message.replace(f"'{spec}'", "SPEC"))
        wait_for_text(page, "not a run directory under", timeout=30, what="the error in the page")
        assert len(set(messages)) == 1, messages
        assert "no such" not in messages[0] and "checkpoint" not in messages[0]
        assert "/no/such/run" in capfd.readouterr().err
        assert live_viewer.source.run.policies["pursuer"].source == "scripted"
        assert_moves(page, live_viewer, "the viewer stopped after the error")
    finally:
        live_viewer.gui.pursuer_policy.value = "scripted"
        page.close()


def check_recording_pages(browser, static_server, viser_path: Path, html_path: Path, tmp_path):
    """The .html plays from disk; the .viser plays in viser's client from a static server."""
    page = browser.new_page(html_path.resolve().as_uri())
    try:
        page.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
    finally:
        page.close()
    site = tmp_path / "site"
    site.mkdir()
    client = Path(viser.__file__).parent / "client" / "build" / "index.html"
    shutil.copy(client, site / "index.html")
    shutil.copy(viser_path, site / "recording.viser")
    base = static_server(site)
    page = browser.new_page(f"{base}/index.html?playbackPath=recording.viser")
    try:
        page.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
    finally:
        page.close()


def test_recording_exports_open_in_the_browser(browser, live_viewer, static_server, tmp_path):
    set_playing(live_viewer, True)
    page, _ = open_viewer(browser, live_viewer)
    try:
        page.click_text("Start recording")
        wait_until(lambda: live_viewer.recording, timeout=10, what="recording")
        time.sleep(2.0)
        page.click_text("Stop recording")
        wait_until(lambda: len(live_viewer.recordings) >= 2, timeout=60, what="the files")
        viser_path, html_path = live_viewer.recordings[-2:]
        assert viser_path.suffix == ".viser" and html_path.suffix == ".html"
        assert viser_path.stat().st_size > 1000
        wait_for_text(page, viser_path.name, timeout=10, what="the saved paths in the page")
    finally:
        page.close()
    check_recording_pages(browser, static_server, viser_path, html_path, tmp_path)


def test_replay_time_slider_and_export(browser, trajectory, static_server, tmp_path):
    viewer = start_viewer(
        replay=trajectory, port=0, speed=10.0, verbose=False, record_dir=tmp_path / "rec"
    )
    try:
        page, _ = open_viewer(browser, viewer)
        wait_until(lambda: viewer.source.index > 3, timeout=20, what="replay to play")
        click_until(page, "Pause", lambda: not viewer.playing, "the Pause click")
        text = page.evaluate("document.body.innerText")
        assert "replay" in text and "Frame" in text
        viewer.seek(0)
        time.sleep(0.7)
        start = robots_mask(page.screenshot())
        viewer.seek(30)
        time.sleep(0.7)
        later = robots_mask(page.screenshot())
        assert int(np.sum(start ^ later)) > 50, "the robots did not move between frames 0 and 30"
        assert int(viewer.gui.frame.value) == 30
        page.click_text("Export replay")
        wait_until(lambda: len(viewer.recordings) >= 2, timeout=120, what="the export")
        page.close()
        check_recording_pages(browser, static_server, *viewer.recordings[-2:], tmp_path)
    finally:
        viewer.stop()


def test_training_view_shows_the_latest_policy(browser, tiny_run):
    viewer = tiny_run.viewer
    page, _ = open_viewer(browser, viewer)
    try:
        text = page.evaluate("document.body.innerText")
        assert f"iteration {tiny_run.iterations}" in text
        assert "training" in text
        assert_moves(page, viewer, "the training view does not play")
    finally:
        page.close()


def attention_pixels(image: np.ndarray) -> int:
    """Pixels of the teammate (green) and obstacle (purple) attention bars (lit, so by hue)."""
    from tests.viewer.browser import scene_region

    rgb = scene_region(image).astype(np.int32)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    green = (g - r >= 50) & (g - b >= 30)
    purple = (b - g >= 40) & (r - g >= 30)
    return int(np.sum(green | purple))


def test_checkpoint_policies_attention_overlay_and_team_mismatch(browser, live_viewer, tiny_run):
    """Loads the tiny run's MIX pursuer into the live viewer by clicking "Load policies"; the
    same run as evader policy does not fit (it learned no evader): an error, the evaders keep
    theirs. Then the attention overlay of pursuer 0 is drawn."""
    set_playing(live_viewer, True)
    page, _ = open_viewer(browser, live_viewer)
    try:
        before = attention_pixels(page.screenshot())
        live_viewer.gui.pursuer_policy.value = str(tiny_run.run_dir)
        live_viewer.gui.evader_policy.value = str(tiny_run.run_dir)
        page.click_text("Load policies")
        wait_until(
            lambda: any("did not learn a evader policy" in e for e in live_viewer.errors),
            timeout=300,
            what="the team mismatch error",
        )
        wait_for_text(
            page, "did not learn a evader policy", timeout=30, what="the error in the page"
        )
        assert live_viewer.source.run.policies["pursuer"].source == str(tiny_run.run_dir)
        assert live_viewer.source.run.policies["evader"].source == "random"
        live_viewer.gui.att_show.value = True
        wait_for_text(page, "self", timeout=30, what="the attention summary")
        # The arena plays on: a frame just after the lone evader's capture shows no evader, so
        # wait for a frame with the overlay and both teams (the next episode brings it back).
        page.wait_for_image(
            lambda im: attention_pixels(im) > before + 100 and shows_both_teams(im),
            timeout=RENDER_TIMEOUT,
        )
    finally:
        live_viewer.gui.att_show.value = False
        live_viewer.gui.pursuer_policy.value = "scripted"
        live_viewer.gui.evader_policy.value = "random"
        page.close()


def forged_cases(v) -> list[tuple[str, object, str]]:
    """(element id, updates, what the error must say) of messages that no honest page sends."""
    return [
        (gui_uuid(v.gui.seed), {"value": 1e30}, "'Seed' = 1e+30 from a browser: must be in [0, "),
        (gui_uuid(v.gui.seed), {"value": 2**64 - 1}, "'Seed' = 18446744073709551615"),
        (gui_uuid(v.gui.arenas), {"value": 65}, "'Arenas' = 65 from a browser: must be in [1, 64]"),
        (gui_uuid(v.gui.arenas), {"value": 2.5}, "'Arenas' = 2.5 from a browser: expected a whole"),
        (
            gui_uuid(v.gui.arenas),
            {"value": "3"},
            "'Arenas' = '3' from a browser: expected a number",
        ),
        (
            gui_uuid(v.gui.speed),
            {"value": float("nan")},
            "'Steps/s' = nan from a browser: expected a",
        ),
        (gui_uuid(v.gui.speed), {"value": float("-inf")}, "'Steps/s' = -inf"),
        (
            gui_uuid(v.gui.apply),
            {"update_cb": []},
            "an update of 'Apply scene' from a browser: only",
        ),
        (gui_uuid(v.gui.apply), {"value": True, "visible": False}, "'Apply scene' = True"),
        (gui_uuid(v.gui.reset), {"value": False}, "'Reset' = False from a browser: not a click"),
        (
            gui_uuid(v.gui.status),
            {"content": "<img src=x onerror=alert(1)>"},
            "an update of an unk",
        ),
        (
            gui_uuid(v.gui.preset),
            {"value": "99-99-99"},
            "'Preset' = '99-99-99' from a browser: exp",
        ),
        (gui_uuid(v.gui.backend), {"value": "warp"}, "'Backend' = 'warp'"),
        (gui_uuid(v.gui.trails), {"value": "false"}, "'Trails' = 'false' from a browser: expected"),
        (gui_uuid(v.gui.pursuer_policy), {"value": "x" * 5000}, "longer than 1024 characters"),
        (gui_uuid(v.gui.pursuer_policy), {"value": "random\x00"}, "holds control characters"),
        (gui_uuid(v.gui.att_agent), {"value": 10**9}, "'Agent' = 1000000000"),
        (gui_uuid(v.gui.frame), {"value": -1}, "'Frame' = -1"),
        ("no-such-element", {"value": 1}, "an unknown GUI element = 1"),
        (gui_uuid(v.gui.seed), ["value", 3], "an update of 'Seed'"),
    ]


def test_forged_messages_are_refused_and_a_fresh_browser_still_plays(browser, live_viewer):
    """Forged GUI messages through a real websocket (viser's protocol): each is refused, shown
    and never applied (no handler removed, no value out of bounds stored); a valid forged
    message still works; then a new connection and a fresh browser page connect and play."""
    v = live_viewer
    set_playing(v, True)
    watched = (v.gui.seed, v.gui.arenas, v.gui.speed, v.gui.preset, v.gui.backend, v.gui.trails)
    watched += (v.gui.pursuer_policy, v.gui.att_agent, v.gui.frame)
    before = [h.value for h in watched]
    handlers = {h.label: list(h._impl.update_cb) for h in (v.gui.apply, v.gui.reset, v.gui.load)}
    rejected, errors = v.guard.rejected, len(v.errors)
    cases = forged_cases(v)
    with ForgedClient(v.port) as client:
        for uuid, updates, _ in cases:
            client.update(uuid, updates)
        client.update(gui_uuid(v.gui.reset), {"value": True})  # the reset after a bad seed
        wait_until(
            lambda: v.guard.rejected >= rejected + len(cases), timeout=30, what="the refusals"
        )
        assert client.receive(0.5) > 0  # the forging client itself is still served
    refusals = v.errors[errors:]
    for _, _, message in cases:
        assert any(message in e for e in refusals), (message, refusals)
    assert [h.value for h in watched] == before
    after = {h.label: list(h._impl.update_cb) for h in (v.gui.apply, v.gui.reset, v.gui.load)}
    assert after == handlers and all(after.values())
    assert np.isfinite(v.speed) and v.source.run.num_arenas == 2
    # A valid forged value is applied: the guard filters, it does not block.
    with ForgedClient(v.port) as client:
        client.update(gui_uuid(v.gui.seed), {"value": 7})
        wait_until(lambda: v.gui.seed.value == 7, timeout=10, what="the valid seed")
        client.update(gui_uuid(v.gui.reset), {"value": True})
        wait_until(lambda: v.source.run.seed == 7, timeout=20, what="the forged reset")
    # New connections are served: a bare websocket, then a real browser that plays.
    with ForgedClient(v.port) as client:
        assert client.receive(1.0) > 0
    page, _ = open_viewer(browser, v)
    try:
        wait_for_text(page, "refused", timeout=30, what="the refusal in the page")
        assert_moves(page, v, "the fresh page does not play")
    finally:
        page.close()


def test_scene_controls_reset_and_apply(browser, live_viewer):
    """Reset with a seed; a scene that cannot be placed is an error and the old one keeps
    running; a valid one (other counts, one arena) replaces it. Runs last: it changes the
    shared viewer's scene."""
    set_playing(live_viewer, True)
    page, _ = open_viewer(browser, live_viewer)
    try:
        live_viewer.gui.seed.value = 7
        page.click_text("Reset")
        wait_until(lambda: live_viewer.source.run.seed == 7, timeout=20, what="the reset")
        live_viewer.gui.pursuers.value = 900
        page.click_text("Apply scene")
        wait_until(
            lambda: any("cannot be placed" in e for e in live_viewer.errors),
            timeout=60,
            what="the placement error on the server",
        )
        wait_for_text(page, "cannot be placed", timeout=30, what="the placement error in the page")
        assert live_viewer.source.run.config.pursuer.num_agents == 4
        assert_moves(page, live_viewer, "the page stopped after the placement error")
        live_viewer.gui.pursuers.value = 3
        live_viewer.gui.obstacles.value = 1
        live_viewer.gui.arenas.value = 1
        page.click_text("Apply scene")
        # The viewer publishes the new source once its scene, first frame and status are sent
        # (`_set_source`), so from here on the page has everything it needs. The name comes
        # first: a screenshot with both teams would also match the old scene (4-1-2 has both),
        # so only after the new status is on the page does "both teams" mean the new scene.
        # The page's wait is the render budget: it covers rebuilding the scene in software
        # WebGL on a loaded machine (and a reconnect, if the websocket was dropped meanwhile).
        wait_until(lambda: live_viewer.source.num_arenas == 1, timeout=300, what="the new scene")
        config = live_viewer.source.run.config
        assert (config.pursuer.num_agents, config.arena.num_obstacles) == (3, 1)
        assert config.name == "3-1-1"
        wait_for_text(page, "3-1-1", timeout=RENDER_TIMEOUT, what="the new scene's name")
        page.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
        assert_moves(page, live_viewer, "the new scene does not play", pixels=20)
    finally:
        page.close()


@pytest.fixture(autouse=True)
def _close_stray_pages(browser):
    yield
    for page in list(browser.pages):
        page.close()
