"""The annotator page in a real headless Chromium against a real server subprocess."""

from __future__ import annotations

import sqlite3

import pytest

pytestmark = pytest.mark.browser

#: Click positions (canvas fractions) on frames 0, 1, 2, 3, 5.
TARGETS = {0: (0.25, 0.5), 1: (0.5, 0.25), 2: (0.75, 0.75), 3: (0.1, 0.9), 5: (0.6, 0.4)}


def _rows(db):
    conn = sqlite3.connect(db)
    try:
        return conn.execute("SELECT operator, frame, timestamp_ns, u, v, visible FROM clicks "
                            "ORDER BY operator, frame").fetchall()
    finally:
        conn.close()


def _wait_frame(page, index):
    page.wait_for_selector(f'#view[data-frame="{index}"][data-state="ready"]', timeout=15000)


def _login(page, url, name):
    page.goto(url)
    page.wait_for_selector("#operator-dialog[open]")
    page.fill("#operator-input", name)
    page.press("#operator-input", "Enter")
    page.wait_for_selector("#operator-dialog:not([open])")


def _click_at(page, fx, fy):
    box = page.locator("#view").bounding_box()
    page.locator("#view").click(position={"x": fx * box["width"], "y": fy * box["height"]})
    return box


def _expected_uv(fx, fy, box, width=320, height=200):
    x, y = fx * box["width"], fy * box["height"]
    return x / box["width"] * width - 0.5, y / box["height"] * height - 0.5


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
    expected = {}
    for index in sorted(TARGETS):
        while page.locator("#view").get_attribute("data-frame") != str(index):
            page.keyboard.press("ArrowRight")
            _wait_frame(page, int(page.evaluate("state.frame")))
        _wait_frame(page, index)
        box = _click_at(page, *TARGETS[index])
        page.wait_for_selector("#own-click.done")
        expected[index] = _expected_uv(*TARGETS[index], box)
        page.wait_for_function(f"document.getElementById('progress-label').textContent === '{len(expected)} of 20 done'")
    page.screenshot(path=str(tmp_path / "annotator.png"))
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
    for index in sorted(TARGETS, reverse=True):
        page.evaluate(f"showFrame({index})")
        _wait_frame(page, index)
        u, v = expected[index]
        assert page.inner_text("#own-click") == f"({u:.1f}, {v:.1f})"

    rows = _rows(db)
    assert [(r[0], r[1]) for r in rows] == [("Operator One", i) for i in sorted(TARGETS)]
    for r in rows:
        u, v = expected[r[1]]
        assert abs(r[3] - u) <= 0.6 and abs(r[4] - v) <= 0.6 and r[5] == 1
    assert len({r[2] for r in rows}) == 5  # each frame's own capture timestamp
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
    _click_at(a, 0.3, 0.3)
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
