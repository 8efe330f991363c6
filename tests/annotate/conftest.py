"""Fixtures of the annotation tests: small synthetic recordings and a real server subprocess."""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from ..conftest import CHROMIUM_ARGS

REPO = Path(__file__).resolve().parents[2]


def synth(out: Path, frames: int, size: str) -> Path:
    """Render a seeded synthetic recording with the real ``fusion-pf synth`` command."""
    subprocess.run(
        [
            sys.executable,
            "-m",
            "fusion_pf",
            "synth",
            str(out),
            "--frames",
            str(frames),
            "--seed",
            "1",
            "--size",
            size,
            "--no-progress",
            "--force",
        ],
        check=True,
        cwd=REPO,
        capture_output=True,
        timeout=120,
    )
    return out


@pytest.fixture(scope="session")
def rec20(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 frames, 320x200 (browser and HTTP tests)."""
    return synth(tmp_path_factory.mktemp("rec") / "r20.mcap", 20, "320x200")


@pytest.fixture(scope="session")
def rec500(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """500 small frames, so 500 clicks per operator are 500 distinct rows (load tests)."""
    return synth(tmp_path_factory.mktemp("rec") / "r500.mcap", 500, "160x100")


class Server:
    """A ``fusion-pf annotate`` subprocess on a free loopback port."""

    def __init__(self, recording: Path, db: Path, *extra: str, preexec_fn=None) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fusion_pf", "annotate", str(recording), "--db", str(db), "--port", "0", *extra],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            preexec_fn=preexec_fn,
        )
        self.url = ""
        self._drain: threading.Thread | None = None
        line = self._first_line(timeout=60.0)
        marker = "open "
        if marker not in line:
            self.stop()
            raise RuntimeError(f"server did not start: {line!r} {self.proc.stderr.read()!r}")
        self.url = line.split(marker, 1)[1].strip().rstrip("/")
        self.port = int(self.url.rsplit(":", 1)[1])
        self.stderr_lines: list[str] = []
        self._drain = threading.Thread(target=self._read_stderr, daemon=True)
        self._drain.start()

    def _first_line(self, timeout: float) -> str:
        out: list[str] = []
        reader = threading.Thread(target=lambda: out.append(self.proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout)
        return out[0] if out else ""

    def _read_stderr(self) -> None:
        for line in self.proc.stderr:
            self.stderr_lines.append(line)

    def kill(self) -> None:
        """SIGKILL the server process and reap it."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        """Terminate the server (SIGTERM, then SIGKILL) and reap it."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()
        if self._drain is not None:
            self._drain.join(timeout=5)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()


#: Idle connections a flood test holds open.
FLOOD_IDLE = 2000


@pytest.fixture
def many_descriptors():
    """Raise this process's soft descriptor limit so it can hold the flood's sockets."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = FLOOD_IDLE + 512
    assert hard == resource.RLIM_INFINITY or hard >= want, f"the hard descriptor limit {hard} cannot hold the flood"
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, want), hard))
    yield
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


@pytest.fixture
def server_factory():
    """``start(recording, db, *extra, preexec_fn=None) -> Server``; every server started is stopped at teardown."""
    started: list[Server] = []

    def start(recording: Path, db: Path, *extra: str, preexec_fn=None) -> Server:
        server = Server(recording, db, *extra, preexec_fn=preexec_fn)
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


@pytest.fixture(scope="module")
def browser():
    """A headless Debian Chromium driven by playwright."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()
