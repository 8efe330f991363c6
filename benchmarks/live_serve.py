"""Does a slow Foxglove client slow the tracker? ``fusion-pf track synth:... --serve`` with and without clients.

Three runs of the same synthetic recording with ``--serve 127.0.0.1:PORT``:
no client, a client that reads every message, and a client that subscribes to
every channel and then stops reading. Prints the tracker's mean frame time
(cues, filter and sinks from the CSV's latency columns, ``--csv-latency``; every run is ``--realtime``) of each
and the ratio to the run without a client.

The client is the ``websockets`` package speaking the Foxglove WebSocket
protocol (subprotocol ``foxglove.sdk.v1``): ``advertise`` -> ``subscribe`` ->
binary message frames (opcode 1: subscription id u32, log time u64, payload,
little-endian). ``tests/commands/test_live.py`` uses the same client.

    python benchmarks/live_serve.py --frames 300 --size 320x200
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import json
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

#: The WebSocket subprotocol of foxglove-sdk's server.
SUBPROTOCOL = "foxglove.sdk.v1"
#: Binary opcode of a message data frame.
MESSAGE_DATA = 1
#: The topics a test or benchmark client subscribes to: the frame and tracker topics of every frame.
TOPICS = (
    "/camera/calibration",
    "/camera/color",
    "/camera/depth",
    "/tracker/estimate",
    "/tracker/overlay",
    "/tracker/particles",
)


def free_port() -> int:
    """A TCP port nobody listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FoxgloveClient:
    """A Foxglove WebSocket client (the ``websockets`` package) in a thread of its own.

    Connects (retrying while the server starts), reads ``serverInfo`` and the
    ``advertise`` messages (the SDK advertises one channel a message, as it
    appears), subscribes to each of ``topics`` as soon as it is advertised (again when it is advertised anew, as
    the Foxglove app does) and, unless ``stall``, keeps every message: ``messages[topic]`` is a
    list of ``(log_time, payload)``. With ``stall`` it stops reading once
    subscribed to every topic (and reads at most one message into the library's queue). ``timeout`` bounds the
    wait for the server and its advertisements: a loaded machine takes tens of seconds to start a run.
    """

    def __init__(self, port: int, topics=TOPICS, *, stall: bool = False, timeout: float = 120.0):
        self.url = f"ws://127.0.0.1:{port}"
        self.topics, self.stall, self.timeout = topics, stall, timeout
        self.channels: dict[str, dict] = {}
        self.messages: dict[str, list[tuple[int, bytes]]] = {}
        self.subprotocol: str | None = None
        #: The server's status messages (e.g. a refused subscription).
        self.status: list[str] = []
        self.closed = False
        self._next_id = 0
        self._by_subscription: dict[int, str] = {}
        self.subscribed = threading.Event()
        self.error: BaseException | None = None
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._main, daemon=True)

    def start(self) -> FoxgloveClient:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._done.set()
        self._thread.join(timeout=self.timeout)

    def _main(self) -> None:
        try:
            asyncio.run(self._session())
        except BaseException as exc:  # reported to the caller
            self.error = exc

    async def _connect(self):
        import websockets

        end = time.monotonic() + self.timeout
        while True:
            try:
                return await websockets.connect(
                    self.url,
                    subprotocols=[SUBPROTOCOL],
                    max_size=None,
                    max_queue=1 if self.stall else 64,
                    close_timeout=1,
                )
            except OSError:
                if time.monotonic() > end:
                    raise
                await asyncio.sleep(0.05)

    async def _subscribe(self, ws, channels: list[dict]) -> None:
        """Subscribe to the wanted topics among the advertised ``channels`` (a topic advertised anew: its new channel)."""
        subs = []
        for ch in channels:
            self.channels[ch["topic"]] = ch
            if ch["topic"] in self.topics:
                self._next_id += 1
                subs.append({"id": self._next_id, "channelId": ch["id"]})
                self._by_subscription[self._next_id] = ch["topic"]
                self.messages.setdefault(ch["topic"], [])
        if subs:
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def _session(self) -> None:
        import websockets

        ws = await self._connect()
        self.subprotocol = ws.subprotocol
        try:
            while not self._done.is_set():
                if self.stall and self.subscribed.is_set():
                    await asyncio.sleep(0.05)
                    continue
                try:
                    data = await asyncio.wait_for(ws.recv(), 0.1 if self.subscribed.is_set() else self.timeout)
                except asyncio.TimeoutError:
                    if not self.subscribed.is_set():
                        raise
                    continue
                except websockets.ConnectionClosed:  # the run ended and its server with it
                    self.closed = True
                    return
                if isinstance(data, bytes):
                    if data[0] == MESSAGE_DATA:
                        sub, log_time = struct.unpack_from("<IQ", data, 1)
                        self.messages[self._by_subscription[sub]].append((log_time, data[13:]))
                    continue
                msg = json.loads(data)
                if msg.get("op") == "advertise":
                    await self._subscribe(ws, msg["channels"])
                    if set(self.topics) <= set(self.messages):
                        self.subscribed.set()
                elif msg.get("op") == "status":
                    self.status.append(msg["message"])
        finally:
            await ws.close()


def frame_ms(csv_path: Path) -> list[float]:
    """Tracker time of every tracked frame in ms: cues, filter and sinks (``latency_total_ms - latency_decode_ms +
    latency_sinks_ms``; decoding is left out because ``--realtime`` waits there for the frame's time)."""
    with open(csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [float(r["latency_total_ms"]) - float(r["latency_decode_ms"]) + float(r["latency_sinks_ms"]) for r in rows]


def run(source: str, out: Path, client: str) -> list[float]:
    """Track ``source`` serving live with ``client`` in ``{"none", "reading", "stalled"}``; its frame times in ms."""
    port = free_port()
    csv_path = out / f"{client}.csv"
    cmd = [sys.executable, "-m", "fusion_pf", "track", source, "-o", out / f"{client}.mcap", "--csv", csv_path]
    cmd += ["--csv-latency", "--force", "--serve", f"127.0.0.1:{port}", "--realtime"]
    proc = subprocess.Popen([str(c) for c in cmd], stderr=subprocess.PIPE, text=True)
    viewer = None
    if client != "none":
        viewer = FoxgloveClient(port, stall=client == "stalled").start()
    _, err = proc.communicate(timeout=600)
    if viewer is not None:
        viewer.stop()
    if proc.returncode != 0:
        raise SystemExit(f"track failed ({proc.returncode}): {err.strip().splitlines()[-1:]}")
    return frame_ms(csv_path)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--size", default="320x200")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--repeats", type=int, default=3, help="runs of each case; the median over runs is reported")
    p.add_argument("--out", type=Path, default=Path("out/bench_live"))
    a = p.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    source = f"synth:seed={a.seed},frames={a.frames},size={a.size}"
    cases = ("none", "reading", "stalled")
    times: dict[str, list[list[float]]] = {c: [] for c in cases}
    for _ in range(a.repeats):
        for c in cases:  # interleaved, so machine load drifts hit every case alike
            times[c].append(run(source, a.out, c))
    print(f"{source}, {a.repeats} runs each, tracker time per frame (cues, filter, sinks):")
    base_mean = statistics.median(statistics.fmean(t) for t in times["none"])
    base_median = statistics.median(statistics.median(t) for t in times["none"])
    for c in cases:
        mean = statistics.median(statistics.fmean(t) for t in times[c])
        median = statistics.median(statistics.median(t) for t in times[c])
        print(
            f"  {c:8s} client: mean {mean:6.2f} ms ({mean / base_mean:.3f} x no client), "
            f"median {median:6.2f} ms ({median / base_median:.3f} x no client)"
        )


if __name__ == "__main__":
    main()
