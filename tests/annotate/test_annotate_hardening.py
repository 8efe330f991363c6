"""Issue 14 item 7 (and 5): the annotation server against hostile requests, mismatched files and stops."""

from __future__ import annotations

import http.client
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import time

import pytest

from fusion_pf.annotate.db import AnnotationDB
from fusion_pf.errors import RecordingError

from .conftest import REPO, Server


def _request(port, method, path, body=b"", headers=None, host=None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        conn.putheader("Host", host or f"127.0.0.1:{port}")
        for key, value in (headers or {}).items():
            conn.putheader(key, value)
        conn.putheader("Content-Length", str(len(body)))
        conn.endheaders(body)
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


def _clicks(db):
    conn = sqlite3.connect(db)
    try:
        return conn.execute("SELECT operator, frame FROM clicks ORDER BY operator, frame").fetchall()
    finally:
        conn.close()


@pytest.fixture(scope="module")
def server(rec20, tmp_path_factory):
    db = tmp_path_factory.mktemp("hard") / "h.sqlite"
    srv = Server(rec20, db)
    try:
        yield srv, db
    finally:
        srv.stop()


def _click(operator="ann", frame=0, u=10, v=10):
    return b'{"operator": "%s", "frame": %d, "u": %s, "v": %s}' % (
        operator.encode(),
        frame,
        str(u).encode(),
        str(v).encode(),
    )


JSON = {"Content-Type": "application/json"}


def test_foreign_host_header_is_refused(server):
    srv, db = server
    port = srv.port
    for host in ("evil.example", f"evil.example:{port}", f"rebind.attacker.test:{port}", f"localhost:{port + 1}"):
        status, body = _request(port, "GET", "/api/frames/0/color", host=host)
        assert status == 421 and b"is not this server" in body, host
        status, _ = _request(port, "POST", "/api/clicks", _click("mallory"), JSON, host=host)
        assert status == 421
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST:{port}"):
        status, _ = _request(port, "GET", "/api/info", host=host)
        assert status == 200, host
    assert ("mallory", 0) not in _clicks(db)


def test_foreign_origin_cannot_write(server):
    srv, db = server
    port = srv.port
    for origin in ("http://evil.example", f"http://evil.example:{port}", "null", f"https://127.0.0.1:{port}"):
        status, body = _request(port, "POST", "/api/clicks", _click("eve"), {**JSON, "Origin": origin})
        assert status == 403 and b"cross-origin write refused" in body, origin
    status, _ = _request(port, "POST", "/api/clicks", _click("eve"), {**JSON, "Sec-Fetch-Site": "cross-site"})
    assert status == 403
    assert ("eve", 0) not in _clicks(db)
    status, _ = _request(port, "POST", "/api/clicks", _click("eve"), {**JSON, "Origin": f"http://127.0.0.1:{port}"})
    assert status == 200 and ("eve", 0) in _clicks(db)


def test_huge_numbers_and_deep_nesting_are_400(server):
    srv, db = server
    port = srv.port
    before = _clicks(db)
    cases = [
        _click(u="9" * 400),
        _click(v="-" + "9" * 400),
        b'{"operator": "a", "frame": ' + b"9" * 400 + b', "u": 1, "v": 1}',
        b"[" * 1000 + b"]" * 1000,
        b'{"operator": "a", "frame": 0, "u": ' + b"[" * 1000 + b"]" * 1000 + b', "v": 1}',
        b'{"operator": "a", "frame": 0, "u": 1, "v": 1, "x": ' + b"9" * 5000 + b"}",
    ]
    for body in cases:
        if len(body) > 4096:
            body = body[:4000] + b"}"  # stays under the body limit, still deeply nested / huge
        status, reply = _request(port, "POST", "/api/clicks", body, JSON)
        assert status == 400, (body[:60], reply[:200])
    assert _clicks(db) == before
    assert not [line for line in srv.stderr_lines if "Traceback" in line]


def test_idle_connections_do_not_block_new_ones(server):
    srv, _ = server
    idle = []
    try:
        for _ in range(150):
            idle.append(socket.create_connection(("127.0.0.1", srv.port), timeout=10))
        started = time.monotonic()
        status, _ = _request(srv.port, "GET", "/api/info")
        elapsed = time.monotonic() - started
    finally:
        for s in idle:
            s.close()
    assert status == 200 and elapsed < 10.0


def test_stop_checkpoints_the_wal_and_ctrl_c_is_quiet(rec20, tmp_path):
    db = tmp_path / "w.sqlite"
    for sig, code in ((signal.SIGINT, 0), (signal.SIGTERM, 0), (signal.SIGHUP, 0)):  # a requested stop: exit 0
        srv = Server(rec20, db)
        try:
            status, _ = _request(srv.port, "POST", "/api/clicks", _click(f"op{sig}"), JSON)
            assert status == 200
            srv.proc.send_signal(sig)
            assert srv.proc.wait(timeout=20) == code
            time.sleep(0.2)
        finally:
            srv.stop()
        assert not [line for line in srv.stderr_lines if "Traceback" in line or "ProgrammingError" in line]
        wal = db.with_name(db.name + "-wal")
        assert not wal.exists() or wal.stat().st_size == 0
        alone = tmp_path / f"alone{sig}" / "w.sqlite"  # the database file by itself holds every click
        alone.parent.mkdir()
        shutil.copy(db, alone)
        assert (f"op{sig}", 0) in _clicks(alone)


def _annotate(recording, db):
    return subprocess.run(
        [sys.executable, "-m", "fusion_pf", "annotate", str(recording), "--db", str(db), "--port", "0"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_database_of_another_recording_with_the_same_shape_is_refused(rec20, tmp_path):
    from drivers.mcap_replay import McapReplay
    from fusion_pf.annotate.db import recording_sha256

    other = tmp_path / "other.mcap"  # same frame count, size and timestamps; another seed
    subprocess.run(
        [
            sys.executable,
            "-m",
            "fusion_pf",
            "synth",
            str(other),
            "--frames",
            "20",
            "--seed",
            "2",
            "--size",
            "320x200",
            "--no-progress",
        ],
        check=True,
        cwd=REPO,
        capture_output=True,
        timeout=120,
    )
    copy = tmp_path / "copy.mcap"
    shutil.copy(rec20, copy)
    db = tmp_path / "a.sqlite"
    with McapReplay(rec20) as replay, McapReplay(other) as replay2:
        assert replay.timestamps.tolist() == replay2.timestamps.tolist()
        first = AnnotationDB(
            db,
            recording=rec20.name,
            n_frames=len(replay),
            width=320,
            height=200,
            sha256=recording_sha256(rec20),
            timestamps=replay.timestamps.tolist(),
        )
        first.set_click("ann", 3, int(replay.timestamps[3]), 5.0, 5.0)
        first.close()
    proc = _annotate(other, db)
    assert proc.returncode == 2 and "holds annotations of another recording" in proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    srv = Server(copy, db)  # a byte-identical copy is the same recording
    srv.stop()


def test_db_in_a_missing_folder_or_a_directory_is_one_line(rec20, tmp_path):
    for db, message in ((tmp_path / "no" / "such" / "a.sqlite", "does not exist"), (tmp_path, "is a directory")):
        proc = _annotate(rec20, db)
        assert proc.returncode == 2 and message in proc.stderr
        assert "Traceback" not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_check_reference_matches(tmp_path):
    from fusion_pf.annotate.db import check_reference_matches

    db_path = tmp_path / "r.sqlite"
    db = AnnotationDB(
        db_path,
        recording="r.mcap",
        n_frames=5,
        width=10,
        height=10,
        sha256="a" * 64,
        timestamps=[100, 200, 300, 400, 500],
    )
    db.set_click("ann", 1, 200, 1.0, 1.0)
    db.set_click("ann", 3, 400, 2.0, 2.0)
    db.close()
    check_reference_matches(db_path, [0, 1, 2, 3, 4], [100, 200, 300, 400, 500], source_sha256="a" * 64)
    check_reference_matches(db_path, [1, 3], [200, 400])  # no hash in an older tracked file: timestamps decide
    with pytest.raises(RecordingError, match="made from another recording"):
        check_reference_matches(db_path, [1, 3], [200, 400], source_sha256="b" * 64)
    with pytest.raises(RecordingError, match="its frame 3 is at t=401 ns, the annotated frame 3 at t=400 ns"):
        check_reference_matches(db_path, [0, 1, 2, 3], [100, 200, 300, 401])
    with pytest.raises(RecordingError, match="has none of the frames annotated"):
        check_reference_matches(db_path, [7, 8], [700, 800])
