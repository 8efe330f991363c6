"""The annotation server over real HTTP: frames, clicks, independence, and bad input (4xx, nothing written)."""

from __future__ import annotations

import http.client
import json
import socket
import sqlite3
import subprocess
import sys

import cv2
import numpy as np
import pytest
import requests

from drivers.mcap_replay import McapReplay
from fusion_pf.errors import InputError

from .conftest import REPO


def _rows(db):
    conn = sqlite3.connect(db)
    try:
        return conn.execute(
            "SELECT operator, frame, timestamp_ns, u, v, visible, clicked_ns FROM clicks ORDER BY operator, frame"
        ).fetchall()
    finally:
        conn.close()


def _raw(port, method, path, body=b"", headers=None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        resp = conn.getresponse()
        return resp.status, resp.getheader("Content-Type"), resp.read()
    finally:
        conn.close()


@pytest.fixture(scope="module")
def served(rec20, tmp_path_factory):
    from .conftest import Server

    db = tmp_path_factory.mktemp("db") / "a.sqlite"
    server = Server(rec20, db)
    try:
        yield server, db
    finally:
        server.stop()


def test_binds_loopback_only(served):
    server, _ = served
    hex_port = f"{server.port:04X}"
    listening = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in open(table).read().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            if state == "0A" and local.endswith(":" + hex_port):
                listening.append(local.split(":")[0])
    assert listening == ["0100007F"]  # 127.0.0.1, nothing else


def test_frames_are_the_recordings_images(served, rec20):
    server, _ = served
    info = requests.get(server.url + "/api/info", timeout=10).json()
    assert info["n_frames"] == 20 and (info["width"], info["height"]) == (320, 200)
    with McapReplay(rec20) as replay:
        frame = replay.frame(7)
    meta = requests.get(server.url + "/api/frames/7/meta", timeout=10).json()
    assert meta == {
        "frame": 7,
        "timestamp_ns": frame.timestamp_ns,
        "width": 320,
        "height": 200,
        "has_depth": frame.depth is not None,
    }
    resp = requests.get(server.url + "/api/frames/7/color", timeout=10)
    assert resp.status_code == 200 and resp.headers["Content-Type"] == "image/jpeg"
    bgr = cv2.imdecode(np.frombuffer(resp.content, np.uint8), cv2.IMREAD_COLOR)
    rgb = bgr[..., ::-1].astype(int)
    assert rgb.shape == frame.color.shape
    assert np.abs(rgb - frame.color.astype(int)).mean() < 6  # JPEG, channel order RGB -> BGR right
    depth = requests.get(server.url + "/api/frames/7/depth", timeout=10)
    assert depth.status_code == 200 and depth.headers["Content-Type"] == "image/png"
    bgra = cv2.imdecode(np.frombuffer(depth.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert bgra.shape == (200, 320, 4)
    assert np.array_equal(bgra[..., 3] == 0, frame.depth == 0)  # holes are transparent
    page = requests.get(server.url + "/", timeout=10)
    assert page.status_code == 200 and 'id="view"' in page.text
    assert "default-src 'self'" in page.headers["Content-Security-Policy"]


def test_others_hidden_until_own_click(served):
    server, db = served
    post = lambda body: requests.post(server.url + "/api/clicks", json=body, timeout=10)
    assert post({"operator": "hid-a", "frame": 2, "u": 100.0, "v": 50.0}).status_code == 200
    view = requests.get(server.url + "/api/frames/2/clicks", params={"operator": "hid-b"}, timeout=10).json()
    assert view["hidden"] is True and view["others"] is None and view["reference"] is None
    answer = post({"operator": "hid-b", "frame": 2, "u": 110.0, "v": 60.0}).json()
    assert answer["hidden"] is False and answer["done"] == 1
    assert [(o["operator"], o["u"], o["v"]) for o in answer["others"]] == [("hid-a", 100.0, 50.0)]
    assert answer["reference"]["mean_u"] == pytest.approx(105.0)
    assert answer["reference"]["spread_px"] == pytest.approx(np.hypot(5, 5))
    again = post({"operator": "hid-b", "frame": 2, "u": None, "v": None}).json()
    assert again["own"]["visible"] is False and again["reference"]["n_not_visible"] == 1
    rows = [r for r in _rows(db) if r[0].startswith("hid-")]
    assert [(r[0], r[1], r[3], r[4], r[5]) for r in rows] == [("hid-a", 2, 100.0, 50.0, 1), ("hid-b", 2, None, None, 0)]


GOOD = {"operator": "bad-input", "frame": 1, "u": 10.0, "v": 10.0}
JSON = {"Content-Type": "application/json"}


@pytest.mark.parametrize(
    ("method", "path", "body", "headers", "status", "message"),
    [
        ("GET", "/static/../db.py", b"", {}, 404, "Not Found"),
        ("GET", "/static/%2e%2e/db.py", b"", {}, 404, "Not Found"),
        ("GET", "/static/..%2fserver.py", b"", {}, 404, "Not Found"),
        ("GET", "/static//etc/passwd", b"", {}, 404, "Not Found"),
        ("GET", "/../../etc/passwd", b"", {}, 404, "Not Found"),
        ("GET", "/api/frames/20/color", b"", {}, 404, "out of range"),
        ("GET", "/api/frames/-1/color", b"", {}, 404, "Not Found"),
        ("GET", "/api/frames/99999999999999999999/meta", b"", {}, 404, "out of range"),
        ("GET", "/api/frames/1/clicks", b"", {}, 400, "'operator' is required"),
        ("GET", "/api/frames/1/clicks?operator=", b"", {}, 400, "empty"),
        ("DELETE", "/api/clicks", b"", {}, 405, "Method Not Allowed"),
        ("POST", "/api/clicks", b"{not json", JSON, 400, "not valid JSON"),
        ("POST", "/api/clicks", b"\xff\xfe", JSON, 400, "not valid JSON"),
        ("POST", "/api/clicks", b"[1, 2]", JSON, 400, "JSON object"),
        ("POST", "/api/clicks", json.dumps(GOOD).encode(), {"Content-Type": "text/plain"}, 415, "application/json"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "u": 320.0}).encode(), JSON, 400, "outside the image"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "v": -3}).encode(), JSON, 400, "outside the image"),
        ("POST", "/api/clicks", b'{"operator": "x", "frame": 1, "u": NaN, "v": 1}', JSON, 400, "NaN"),
        ("POST", "/api/clicks", b'{"operator": "x", "frame": 1, "u": 1e999, "v": 1}', JSON, 400, "outside"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "frame": 20}).encode(), JSON, 400, "out of range"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "frame": "1"}).encode(), JSON, 400, "integer"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "u": None}).encode(), JSON, 400, "number"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "operator": "x" * 65}).encode(), JSON, 400, "at most 64"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "extra": 1}).encode(), JSON, 400, "unknown keys"),
        ("POST", "/api/clicks", json.dumps({"operator": "x", "frame": 1}).encode(), JSON, 400, "missing keys"),
        ("POST", "/api/clicks", json.dumps({**GOOD, "operator": "a" * 5000}).encode(), JSON, 413, "at most 4096"),
    ],
)
def test_bad_requests_get_4xx_json_and_write_nothing(served, method, path, body, headers, status, message):
    server, db = served
    before = _rows(db)
    got, ctype, data = _raw(server.port, method, path, body, headers)
    assert got == status, data
    assert ctype == "application/json"
    assert message in json.loads(data)["error"]
    assert _rows(db) == before


def test_oversized_and_chunked_bodies_are_refused(served):
    server, db = served
    before = _rows(db)
    big = json.dumps({**GOOD, "operator": "a" * 40}).encode() + b" " * 200_000
    status, _, data = _raw(server.port, "POST", "/api/clicks", big, JSON)
    assert status == 413 and b"at most" in data
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as s:
        chunk = b" " * 8000
        s.sendall(
            b"POST /api/clicks HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nContent-Type: application/json\r\n"
            b"Transfer-Encoding: chunked\r\nConnection: close\r\n\r\n"
            % server.port
            + b"%x\r\n" % len(chunk)
            + chunk
            + b"\r\n0\r\n\r\n"
        )
        reply = b""
        while chunk_in := s.recv(65536):
            reply += chunk_in
    assert reply.split(b" ", 2)[1] == b"413"
    assert _rows(db) == before
    assert not [line for line in server.stderr_lines if "Traceback" in line]


def test_database_of_another_recording_fails_cleanly(rec20, tmp_path):
    db = tmp_path / "other.sqlite"
    conn = sqlite3.connect(db)
    conn.executescript(
        "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);"
        "INSERT INTO meta VALUES ('n_frames', '111'), ('recording', 'paper.mcap');"
    )
    conn.close()
    proc = subprocess.run(
        [sys.executable, "-m", "fusion_pf", "annotate", str(rec20), "--db", str(db), "--port", "0"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "'paper.mcap' with n_frames = 111" in proc.stderr and "Traceback" not in proc.stderr


def test_frame_images_lru_cache(rec20):
    from fusion_pf.annotate.frames import FrameImages, ReplayProvider

    with McapReplay(rec20) as replay:
        with pytest.raises(InputError, match="len\\(\\) and get"):
            FrameImages(replay)  # a replay has frame(), not get(): needs the adapter
        images = FrameImages(ReplayProvider(replay), color_format="png", cache_size=3)
        first = images.color(0)
        assert images.color(0) is first and images.hits == 1  # colour and depth of 0 cached
        images.color(1)  # evicts the oldest entry (depth of frame 0)
        assert images.color(0) is first and images.hits == 2
        images.depth(0)
        assert images.misses == 3  # frame 0 re-decoded for its depth only
        png = cv2.imdecode(np.frombuffer(images.color(2), np.uint8), cv2.IMREAD_COLOR)
        assert np.array_equal(png[..., ::-1], replay.frame(2).color)  # PNG is lossless
        with pytest.raises(InputError, match="out of range"):
            images.color(20)
