"""The annotator page in a real headless Chromium against a real server subprocess."""

from __future__ import annotations

import socket
import sqlite3
import threading
import time

import pytest
from playwright.sync_api import expect

from drivers.mcap_replay import McapReplay

from .conftest import FLOOD_IDLE

pytestmark = pytest.mark.browser

#: Frames the operator clicks (on the true palm centre of the synthetic scene).
FRAMES = (0, 1, 2, 3, 5)


def _rows(db):
    conn = sqlite3.connect(db)
    try:
        return conn.execute(
            "SELECT operator, frame, timestamp_ns, u, v, visible FROM clicks ORDER BY operator, frame"
        ).fetchall()
    finally:
        conn.close()


def _wait_frame(page, index):
    page.wait_for_selector(f'#view[data-frame="{index}"][data-state="ready"]', timeout=15000)


def _login(page, url, name):
    page.goto(url)
    page.wait_for_selector("#operator-dialog[open]")
    page.fill("#operator-input", name)
    page.press("#operator-input", "Enter")
    expect(page.locator("#operator-label")).to_have_text(name, timeout=15000)


def _click_palm(page, u, v, width=320, height=200):
    """Bring image point (u, v) into view and click it with the mouse, like an operator."""
    page.evaluate(
        """([u, v]) => {
            const viewer = document.getElementById("viewer");
            viewer.scrollLeft = (u + 0.5) * state.zoom - viewer.clientWidth / 2;
            viewer.scrollTop = (v + 0.5) * state.zoom - viewer.clientHeight / 2;
        }""",
        [u, v],
    )
    box = page.locator("#view").bounding_box()
    page.mouse.click(box["x"] + (u + 0.5) / width * box["width"], box["y"] + (v + 0.5) / height * box["height"])
    return box["width"] / width  # screen pixels per image pixel


def test_operator_clicks_navigates_reloads(browser, server_factory, rec20, tmp_path):
    db = tmp_path / "a.sqlite"
    server = server_factory(rec20, db)
    page = browser.new_page(viewport={"width": 1100, "height": 650})
    errors = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    _login(page, server.url + "/", "Operator One")
    _wait_frame(page, 0)
    assert page.inner_text("#frame-label") == "Frame 0 / 20"
    assert page.inner_text("#progress-label") == "0 of 20 done"
    with McapReplay(rec20) as replay:
        truth = {i: replay.frame(i) for i in FRAMES}
    scale = {}
    for n_done, index in enumerate(FRAMES, start=1):
        while page.locator("#view").get_attribute("data-frame") != str(index):
            page.keyboard.press("ArrowRight")
            _wait_frame(page, int(page.evaluate("state.frame")))
        _wait_frame(page, index)
        if index == 5:  # zoom in twice with the keyboard; the click must still land on the palm
            zoom_before = page.inner_text("#zoom-label")
            page.keyboard.press("+")
            page.keyboard.press("+")
            assert page.inner_text("#zoom-label") != zoom_before
        gt = truth[index].ground_truth
        scale[index] = _click_palm(page, gt.u, gt.v)
        expect(page.locator("#progress-label")).to_have_text(f"{n_done} of 20 done")
        expect(page.locator("#own-click")).to_have_class("value done")
    assert scale[5] > scale[3] * 1.4
    page.keyboard.press("d")  # depth overlay for the screenshot
    _wait_frame(page, 5)
    page.screenshot(path=str(tmp_path / "annotator.png"))
    page.keyboard.press("d")
    page.keyboard.press("0")
    # keys: left goes back, n jumps to the first frame not done after the current one
    page.keyboard.press("ArrowLeft")
    _wait_frame(page, 4)
    assert page.inner_text("#own-click").startswith("not done yet")
    page.keyboard.press("Home")
    _wait_frame(page, 0)
    page.keyboard.press("n")
    _wait_frame(page, 4)
    page.keyboard.press("n")
    _wait_frame(page, 6)

    page.reload()
    _wait_frame(page, 6)  # the frame is kept in the URL, the name in localStorage
    assert page.inner_text("#operator-label") == "Operator One"
    assert page.inner_text("#progress-label") == "5 of 20 done"
    rows = _rows(db)
    stored = {r[1]: (r[3], r[4]) for r in rows}
    assert [(r[0], r[1], r[2], r[5]) for r in rows] == [("Operator One", i, truth[i].timestamp_ns, 1) for i in FRAMES]
    for i in FRAMES:  # the stored click is the palm the mouse hit, to a screen pixel
        gt = truth[i].ground_truth
        assert abs(stored[i][0] - gt.u) <= 1.0 / scale[i] + 0.05
        assert abs(stored[i][1] - gt.v) <= 1.0 / scale[i] + 0.05
    for index in reversed(FRAMES):
        while page.locator("#view").get_attribute("data-frame") != str(index):
            page.keyboard.press("ArrowLeft")
            _wait_frame(page, int(page.evaluate("state.frame")))
        u, v = stored[index]
        assert page.inner_text("#own-click") == f"({u:.1f}, {v:.1f})"
    assert errors == []
    page.close()


def test_two_operators_at_once(browser, server_factory, rec20, tmp_path):
    db = tmp_path / "b.sqlite"
    server = server_factory(rec20, db)
    ctx_a, ctx_b = browser.new_context(), browser.new_context()
    a, b = ctx_a.new_page(), ctx_b.new_page()
    _login(a, server.url + "/#frame=4", "alice")
    _login(b, server.url + "/#frame=4", "bob")
    _wait_frame(a, 4)
    _wait_frame(b, 4)
    _click_palm(a, 96.0, 60.0)
    a.wait_for_selector("#own-click.done")
    assert a.inner_text("#ref-label") == "Nobody else has done this frame yet."
    b.keyboard.press("ArrowLeft")
    _wait_frame(b, 3)
    b.keyboard.press("ArrowRight")
    _wait_frame(b, 4)
    # bob has not done frame 4: alice's click stays hidden
    assert b.is_visible("#others-hidden") and b.locator("#others li").count() == 0
    b.keyboard.press("x")
    b.wait_for_selector("#own-click.done")
    assert b.inner_text("#own-click") == "not visible"
    assert b.locator("#others li").count() == 1 and "alice" in b.inner_text("#others")
    assert b.inner_text("#ref-label").startswith("Mean of 1:")
    a.keyboard.press("ArrowRight")
    _wait_frame(a, 5)
    a.keyboard.press("ArrowLeft")
    _wait_frame(a, 4)
    assert "bob" in a.inner_text("#others") and "not visible" in a.inner_text("#others")
    assert [(r[0], r[1], r[5]) for r in _rows(db)] == [("alice", 4, 1), ("bob", 4, 0)]
    ctx_a.close()
    ctx_b.close()


@pytest.mark.slow
def test_the_page_keeps_working_through_a_connection_flood(browser, many_descriptors, server_factory, rec20, tmp_path):
    """Default caps: the flood shares 127.0.0.1 with the browser, whose idle keep-alive connections it closes too."""
    db = tmp_path / "f.sqlite"
    server = server_factory(rec20, db)
    page = browser.new_page(viewport={"width": 1100, "height": 650})
    errors = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    _login(page, server.url + "/", "flooded")
    _wait_frame(page, 0)
    stop = threading.Event()
    held: list[socket.socket] = []
    attempts = [0]

    def flood() -> None:  # hold FLOOD_IDLE idle connections, then open and close until stopped (bounded)
        end = time.monotonic() + 60
        while not stop.is_set() and attempts[0] < 50_000 and time.monotonic() < end:
            try:
                conn = socket.create_connection(("127.0.0.1", server.port), timeout=5)
                if len(held) < FLOOD_IDLE:
                    held.append(conn)
                else:
                    conn.close()
            except OSError:
                pass
            attempts[0] += 1

    flooder = threading.Thread(target=flood)
    flooder.start()
    slowest = 0.0
    try:
        while attempts[0] < 1000 and flooder.is_alive():  # the flood is under way
            time.sleep(0.05)
        for index in range(1, 6):
            t0 = time.monotonic()
            page.keyboard.press("ArrowRight")
            _wait_frame(page, index)
            _click_palm(page, 96.0, 60.0)
            expect(page.locator("#progress-label")).to_have_text(f"{index} of 20 done")
            slowest = max(slowest, time.monotonic() - t0)
        during = attempts[0]
        flooding = flooder.is_alive()
    finally:
        stop.set()
        flooder.join(timeout=70)
        for conn in held:
            conn.close()
    print(f"\nflood: frame shown and click acknowledged in <= {slowest:.3f} s, {during} connection attempts meanwhile")
    assert flooding and during > 1000 and not flooder.is_alive()  # every step ran during the flood
    assert slowest < 2.0 * 2  # two round trips (frame, click), each within the 2 s an operator may wait
    assert server.proc.poll() is None and errors == []
    assert [(r[0], r[1]) for r in _rows(db)] == [("flooded", i) for i in range(1, 6)]
