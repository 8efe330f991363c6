"""Load and durability over real HTTP on loopback: 8 operators x 500 clicks, and SIGKILL mid-way."""

from __future__ import annotations

import sqlite3
import threading
import time

import numpy as np
import requests

N_OPERATORS = 8
CLICKS_EACH = 500


def _uv(op: int, frame: int) -> tuple[float, float]:
    """A distinct, reproducible position inside the 160x100 image for every (operator, frame)."""
    return float((op * 37 + frame * 13) % 1590) / 10.0, float((op * 11 + frame * 7) % 990) / 10.0


def _operator(
    url: str, op: int, frames: range, acked: list, latencies: list, stop: threading.Event, errors: list
) -> None:
    session = requests.Session()
    name = f"load-{op}"
    for frame in frames:
        if stop.is_set():
            return
        u, v = _uv(op, frame)
        t0 = time.perf_counter_ns()
        try:
            resp = session.post(
                f"{url}/api/clicks", json={"operator": name, "frame": frame, "u": u, "v": v}, timeout=30
            )
        except requests.RequestException:
            return  # the server was killed: this click was never acknowledged
        latencies.append(time.perf_counter_ns() - t0)
        if resp.status_code != 200:
            errors.append((resp.status_code, resp.text))
            return
        own = resp.json()["own"]
        acked.append((name, own["frame"], own["u"], own["v"]))


def _run_operators(url, frames, stop=None):
    stop = stop or threading.Event()
    acked, latencies, errors = [], [], []
    threads = [
        threading.Thread(target=_operator, args=(url, op, frames, acked, latencies, stop, errors))
        for op in range(N_OPERATORS)
    ]
    for t in threads:
        t.start()
    return threads, acked, latencies, errors


def _db_rows(db):
    conn = sqlite3.connect(db)
    try:
        return {(r[0], r[1]): (r[2], r[3]) for r in conn.execute("SELECT operator, frame, u, v FROM clicks")}
    finally:
        conn.close()


def test_eight_operators_500_clicks_each(server_factory, rec500, tmp_path, record_property):
    db = tmp_path / "load.sqlite"
    server = server_factory(rec500, db)
    t0 = time.perf_counter()
    threads, acked, latencies, errors = _run_operators(server.url, range(CLICKS_EACH))
    for t in threads:
        t.join(timeout=110)
    elapsed = time.perf_counter() - t0
    assert not any(t.is_alive() for t in threads), "load test exceeded its time bound"
    assert errors == []
    assert len(acked) == N_OPERATORS * CLICKS_EACH
    rows = _db_rows(db)
    assert len(rows) == N_OPERATORS * CLICKS_EACH
    for op in range(N_OPERATORS):
        for frame in range(CLICKS_EACH):
            assert rows[(f"load-{op}", frame)] == _uv(op, frame)
    rate = len(acked) / elapsed
    p95_ms = float(np.percentile(latencies, 95)) / 1e6
    record_property("clicks_per_s", round(rate, 1))
    record_property("p95_ms", round(p95_ms, 2))
    print(
        f"\nload: {len(acked)} clicks in {elapsed:.2f} s = {rate:.0f} clicks/s, "
        f"p50 {np.percentile(latencies, 50) / 1e6:.2f} ms, p95 {p95_ms:.2f} ms"
    )
    assert p95_ms < 2000  # generous: 2 shared cores; a human clicks ~1/s
    done = requests.get(f"{server.url}/api/operators/load-3/clicks", timeout=10).json()
    assert done["done"] == CLICKS_EACH and done["n_frames"] == CLICKS_EACH


def test_acknowledged_clicks_survive_sigkill(server_factory, rec500, tmp_path):
    db = tmp_path / "kill.sqlite"
    server = server_factory(rec500, db)
    stop = threading.Event()
    threads, acked, _, errors = _run_operators(server.url, range(CLICKS_EACH), stop)
    deadline = time.monotonic() + 60
    while len(acked) < 400 and time.monotonic() < deadline and not errors:
        time.sleep(0.005)
    server.kill()  # SIGKILL while the operators are still clicking
    stop.set()
    for t in threads:
        t.join(timeout=30)
    assert errors == []
    assert not any(t.is_alive() for t in threads)
    snapshot = list(acked)
    assert 400 <= len(snapshot) < N_OPERATORS * CLICKS_EACH, "the kill did not happen mid-way"

    restarted = server_factory(rec500, db)
    rows = _db_rows(db)
    missing = [a for a in snapshot if rows.get((a[0], a[1])) != (a[2], a[3])]
    assert missing == []
    over_http = requests.get(f"{restarted.url}/api/operators/load-0/clicks", timeout=10).json()
    acked_0 = {(a[1], a[2], a[3]) for a in snapshot if a[0] == "load-0"}
    assert acked_0 <= {(c["frame"], c["u"], c["v"]) for c in over_http["clicks"]}
    resp = requests.post(
        f"{restarted.url}/api/clicks", json={"operator": "after", "frame": 0, "u": 1.0, "v": 2.0}, timeout=10
    )
    assert resp.status_code == 200 and _db_rows(db)[("after", 0)] == (1.0, 2.0)
