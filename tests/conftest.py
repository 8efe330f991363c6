"""Test helpers shared by every test folder.

* ``fusion_pf`` fixture: run the ``fusion-pf`` command line in a subprocess,
  ``fusion_pf(*args, timeout=300) -> subprocess.CompletedProcess`` (text output);
  arguments are converted with ``str``.
* ``stream_normals`` fixture: ``stream_normals(state, shape) -> float32 array``, the next
  normals of a particle-filter kernel stream, drawn by numpy itself from the same state.
* ``rerun_process(*args)``: the rerun-sdk wheel's ``rerun`` command as a context manager.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import drivers  # noqa: F401  (before any test module imports depthai: drivers sets its environment)


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C as in a terminal, wherever the tests run.

    A background job of a non-interactive shell (``cmd &`` in a script, nohup) starts with SIGINT ignored, and
    so would every command a test starts: the tests of Ctrl-C would then see it lost (a recording sent SIGINT
    kept recording). Python's own handler here makes the children start with the default action too.
    """
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


#: Flags of the headless Debian Chromium the browser tests drive with playwright.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

#: The command line as a subprocess runs it (the interpreter of the test run).
CLI = (sys.executable, "-m", "fusion_pf")


def run_cli(*args: object, timeout: float = 300) -> subprocess.CompletedProcess:
    """``fusion-pf ARGS`` in a subprocess; stdout and stderr captured as text."""
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@contextlib.contextmanager
def rerun_process(*args: object) -> Iterator[subprocess.Popen]:
    """``rerun ARGS`` (the rerun-sdk wheel's command, beside the interpreter) in its own process group, ended
    with SIGTERM to the whole group: the command is a launcher whose viewer binary is its child, which
    terminating the launcher alone left running after the suite."""
    proc = subprocess.Popen(
        [Path(sys.executable).with_name("rerun"), *map(str, args)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        yield proc
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)


@pytest.fixture(scope="session")
def fusion_pf():
    """The command line in a subprocess (:func:`run_cli`); a plain function, so any fixture may use it."""
    return run_cli


def _stream_normals(state: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Normals of a kernel stream ``(a, b, c, counter, has_uint32, uinteger)`` (:func:`fusion_pf.filter.kernel.stream`),
    drawn by numpy's own SFC64 and float32 ziggurat from a copy of the state (the reference the kernels must match)."""
    bg = np.random.SFC64()
    bg.state = {
        "bit_generator": "SFC64",
        "state": {"state": state[:4].copy()},
        "has_uint32": int(state[4]),
        "uinteger": int(state[5]),
    }
    return np.random.Generator(bg).standard_normal(int(np.prod(shape)), dtype=np.float32).reshape(shape)


@pytest.fixture(scope="session")
def stream_normals():
    """:func:`_stream_normals` (a plain function)."""
    return _stream_normals
