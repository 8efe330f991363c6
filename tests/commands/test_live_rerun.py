"""``fusion-pf track --rerun``: the tracking in Rerun's web viewer (shipped in the rerun-sdk wheel), in headless Chromium."""

import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ..conftest import CHROMIUM_ARGS, rerun_process, run_cli
from .test_live import live_serve

pytestmark = pytest.mark.browser


def _shot(page, path: Path) -> np.ndarray:
    # the viewer renders in software (no GPU); beside another test worker one frame took over playwright's 30 s default
    page.screenshot(path=path, timeout=120_000)
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.int16)


def _changed(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of the pixels that differ between two screenshots."""
    return float((np.abs(a - b).sum(axis=2) > 60).mean())


def _settled(page, path: Path, within_s: float) -> np.ndarray:
    """A screenshot once the page stopped changing (two shots a second apart alike), or after ``within_s``."""
    shot = _shot(page, path)
    end = time.monotonic() + within_s
    while time.monotonic() < end:
        time.sleep(1.0)
        shot, previous = _shot(page, path), shot
        if _changed(shot, previous) < 0.01:
            break
    return shot


def test_the_live_tracking_shows_in_rerun_s_web_viewer(tmp_path):
    from playwright.sync_api import sync_playwright

    grpc, web = live_serve.free_port(), live_serve.free_port()
    url = f"rerun+http://127.0.0.1:{grpc}/proxy"
    with rerun_process("--serve-web", "--bind", "127.0.0.1", "--port", grpc, "--web-viewer-port", web):
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            for _ in range(200):  # the viewer's web server starts
                try:
                    page.goto(f"http://127.0.0.1:{web}/?url={url}")
                    break
                except Exception:
                    time.sleep(0.05)
            time.sleep(8)  # the viewer loads (its page changes on the way), then settles: a loaded machine is slower
            before = _settled(page, tmp_path / "before.png", within_s=60.0)
            r = run_cli("track", "synth:seed=1,frames=60,size=320x200", "-o", tmp_path / "o.mcap", "--rerun", url)
            assert r.returncode == 0, r.stderr
            assert f"live view for Rerun at {url}" in r.stderr
            end = time.monotonic() + 90.0  # until the views show, bounded
            while True:
                time.sleep(1.0)
                after = _shot(page, tmp_path / "rerun_live.png")
                if (_changed(after, before) > 0.15 and after.std() > 30) or time.monotonic() > end:
                    break
            browser.close()
    print(f"screenshot: {tmp_path / 'rerun_live.png'}")
    # the empty viewer turned into image views: a large part of the page changed and is far from uniform
    changed = _changed(after, before)
    assert changed > 0.15, changed
    assert after.std() > 30
