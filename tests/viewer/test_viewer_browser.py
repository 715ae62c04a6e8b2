"""The viewer in a real headless Chromium: what a person would see and do.

Every test opens the page, looks at screenshots (team colours, robots moving or not) and acts
through the browser (real mouse clicks on the GUI's buttons). Server-side handles are only used to
set up a state or to read what the server did.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import viser
from PIL import Image
from viewer_helpers import robots_mask, shows_both_teams, team_counts, wait_until

from pe_mjx.viewer import start_viewer

RENDER_TIMEOUT = 90.0


def open_viewer(browser, url: str):
    page = browser.new_page(url)
    image = page.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
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
    """Waits until `text` is part of what the page shows."""
    wait_until(lambda: text in page.evaluate("document.body.innerText"), timeout=timeout, what=what)


def set_playing(viewer, playing: bool) -> None:
    viewer.call(lambda: viewer._set_playing(playing))


def moved(page, seconds: float = 1.5, tries: int = 3) -> int:
    """Pixels of robot colour that changed between two screenshots `seconds` apart (the largest
    over a few tries: a finished episode holds its last frame for a moment)."""
    best = 0
    for _ in range(tries):
        before = robots_mask(page.screenshot())
        time.sleep(seconds)
        after = robots_mask(page.screenshot())
        best = max(best, int(np.sum(before ^ after)))
        if best > 50:
            break
    return best


def test_page_shows_both_teams(browser, live_viewer, tmp_path):
    page, image = open_viewer(browser, live_viewer.url)
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
    page, _ = open_viewer(browser, live_viewer.url)
    try:
        assert moved(page) > 50, "robots did not move while playing"
        # A real mouse click in the browser.
        click_until(page, "Pause", lambda: not live_viewer.playing, "the Pause click")
        time.sleep(0.5)  # let the last frame arrive
        frames = live_viewer.frames_streamed
        changed = moved(page, tries=1)
        assert changed <= 10, f"{changed} robot pixels changed while paused"
        assert live_viewer.frames_streamed == frames
        click_until(page, "Play", lambda: live_viewer.playing, "the Play click")
        assert moved(page) > 50, "robots did not move again after Play"
    finally:
        page.close()


def test_step_button_advances_one_step(browser, live_viewer):
    set_playing(live_viewer, True)  # paused, both evaders may be down: no blue to wait for
    page, _ = open_viewer(browser, live_viewer.url)
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
    first, _ = open_viewer(browser, live_viewer.url)
    second, _ = open_viewer(browser, live_viewer.url)
    try:
        wait_until(lambda: live_viewer.num_clients() == 2, timeout=20, what="two clients")
        assert moved(first) > 50 and moved(second) > 50
        second.close()
        wait_until(lambda: live_viewer.num_clients() == 1, timeout=20, what="the tab to leave")
        assert live_viewer._thread.is_alive()
        assert moved(first) > 50, "the remaining tab stopped updating"
        first.reload()
        first.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
        wait_until(lambda: live_viewer.num_clients() == 1, timeout=20, what="the reloaded tab")
        assert moved(first) > 50
    finally:
        first.close()
        second.close()
    # A tab closing never stops the server: a new one still gets the scene.
    third, _ = open_viewer(browser, live_viewer.url)
    third.close()


def test_bad_policy_path_is_an_error_in_the_page_and_the_server_keeps_running(
    browser, live_viewer, capfd
):
    set_playing(live_viewer, True)
    page, _ = open_viewer(browser, live_viewer.url)
    try:
        live_viewer.gui_pursuer_policy.value = "/no/such/run"
        page.click_text("Load policies")
        wait_for_text(page, "no such directory", timeout=30, what="the error in the page")
        assert any("/no/such/run" in e for e in live_viewer.errors)
        assert "/no/such/run" in capfd.readouterr().err
        assert live_viewer.source.run.policies["pursuer"].label == "scripted"
        assert moved(page) > 50, "the viewer stopped after the error"
    finally:
        live_viewer.gui_pursuer_policy.value = "scripted"
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
    page, _ = open_viewer(browser, live_viewer.url)
    try:
        page.click_text("Start recording")
        wait_until(lambda: live_viewer._serializer is not None, timeout=10, what="recording")
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
        page, _ = open_viewer(browser, viewer.url)
        wait_until(lambda: viewer.source.index > 3, timeout=20, what="replay to play")
        click_until(page, "Pause", lambda: not viewer.playing, "the Pause click")
        text = page.evaluate("document.body.innerText")
        assert "replay" in text and "Frame" in text
        viewer.call(lambda: viewer._seek(0))
        time.sleep(0.7)
        start = robots_mask(page.screenshot())
        viewer.call(lambda: viewer._seek(30))
        time.sleep(0.7)
        later = robots_mask(page.screenshot())
        assert int(np.sum(start ^ later)) > 50, "the robots did not move between frames 0 and 30"
        assert int(viewer.gui_frame.value) == 30
        page.click_text("Export replay")
        wait_until(lambda: len(viewer.recordings) >= 2, timeout=120, what="the export")
        page.close()
        check_recording_pages(browser, static_server, *viewer.recordings[-2:], tmp_path)
    finally:
        viewer.stop()


def test_training_view_shows_the_latest_policy(browser, tiny_run):
    viewer = tiny_run.viewer
    page, _ = open_viewer(browser, viewer.url)
    try:
        text = page.evaluate("document.body.innerText")
        assert f"iteration {tiny_run.iterations}" in text
        assert "training" in text
        assert moved(page) > 50
    finally:
        page.close()


def attention_pixels(image: np.ndarray) -> int:
    """Pixels of the teammate (green) and obstacle (purple) attention bars (lit, so by hue)."""
    from pe_mjx.viewer.browser import scene_region

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
    page, _ = open_viewer(browser, live_viewer.url)
    try:
        before = attention_pixels(page.screenshot())
        live_viewer.gui_pursuer_policy.value = str(tiny_run.run_dir)
        live_viewer.gui_evader_policy.value = str(tiny_run.run_dir)
        page.click_text("Load policies")
        wait_until(
            lambda: any("did not learn a evader policy" in e for e in live_viewer.errors),
            timeout=300,
            what="the team mismatch error",
        )
        wait_for_text(
            page, "did not learn a evader policy", timeout=30, what="the error in the page"
        )
        assert live_viewer.source.run.policies["pursuer"].label == str(tiny_run.run_dir)
        assert live_viewer.source.run.policies["evader"].label == "random"
        live_viewer.gui_att_show.value = True
        wait_for_text(page, "self", timeout=30, what="the attention summary")
        image = page.wait_for_image(
            lambda im: attention_pixels(im) > before + 100, timeout=RENDER_TIMEOUT
        )
        assert shows_both_teams(image)
    finally:
        live_viewer.gui_att_show.value = False
        live_viewer.gui_pursuer_policy.value = "scripted"
        live_viewer.gui_evader_policy.value = "random"
        page.close()


def test_scene_controls_reset_and_apply(browser, live_viewer):
    """Reset with a seed; a scene that cannot be placed is an error and the old one keeps
    running; a valid one (other counts, one arena) replaces it. Runs last: it changes the
    shared viewer's scene."""
    set_playing(live_viewer, True)
    page, _ = open_viewer(browser, live_viewer.url)
    try:
        live_viewer.gui_seed.value = 7
        page.click_text("Reset")
        wait_until(lambda: live_viewer.source.run.seed == 7, timeout=20, what="the reset")
        live_viewer.gui_pursuers.value = 900
        page.click_text("Apply scene")
        wait_until(
            lambda: any("cannot be placed" in e for e in live_viewer.errors),
            timeout=60,
            what="the placement error on the server",
        )
        wait_for_text(page, "cannot be placed", timeout=30, what="the placement error in the page")
        assert live_viewer.source.run.config.pursuer.num_agents == 4
        assert moved(page) > 50
        live_viewer.gui_pursuers.value = 3
        live_viewer.gui_obstacles.value = 1
        live_viewer.gui_arenas.value = 1
        page.click_text("Apply scene")
        wait_until(lambda: live_viewer.source.num_arenas == 1, timeout=300, what="the new scene")
        config = live_viewer.source.run.config
        assert (config.pursuer.num_agents, config.arena.num_obstacles) == (3, 1)
        assert config.name == "3-1-1"
        page.wait_for_image(shows_both_teams, timeout=RENDER_TIMEOUT)
        wait_for_text(page, "3-1-1", timeout=30, what="the new scene's name in the page")
        assert moved(page) > 20
    finally:
        page.close()


@pytest.fixture(autouse=True)
def _close_stray_pages(browser):
    yield
    for page in list(browser.pages):
        page.close()
