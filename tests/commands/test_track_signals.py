"""Issue 24 item 3: ``track`` finalises its MCAP and CSV on SIGTERM and SIGHUP, from the first moment on.

The command runs in its own session (``start_new_session``), as from a
terminal; the signal is sent after frames were written, at the moment the
process starts handling it (read from ``/proc/PID/status``, during start-up,
before the commands are imported), and 0.3 s after the start (or then, on a loaded
machine whose interpreter starts slower).
"""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

CLI = [sys.executable, "-m", "fusion_pf"]
ENDLESS = "synth:frames=100000,size=160x100"
SIGNALS = [(signal.SIGTERM, 143), (signal.SIGHUP, 129)]


def start_track(tmp_path: Path) -> tuple[subprocess.Popen, Path, Path]:
    out, table = tmp_path / "out.mcap", tmp_path / "out.csv"
    proc = subprocess.Popen(
        [*CLI, "track", ENDLESS, "-o", str(out), "--csv", str(table), "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    return proc, out, table


def handles(pid: int, sig: int) -> bool:
    """Whether the process has a handler for ``sig`` (the SigCgt mask of /proc/PID/status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = next(int(line.split()[1], 16) for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(caught >> (sig - 1) & 1)


def stop(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=120)
    return proc.returncode, stderr


def check_outputs(out: Path, table: Path) -> int:
    """The MCAP is complete (summary, footer) and its /tracker/estimate messages are the CSV's rows."""
    with open(out, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        estimates = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/tracker/estimate"])]
    assert summary is not None and summary.statistics is not None
    with open(table, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["frame"]) for r in rows] == [e["frame"] for e in estimates]
    assert [int(r["timestamp_ns"]) for r in rows] == [e["timestamp_ns"] for e in estimates]
    return len(rows)


@pytest.mark.parametrize("sig, code", SIGNALS)
def test_track_finalises_on_terminate_and_hangup_after_frames(tmp_path, sig, code):
    proc, out, table = start_track(tmp_path)
    deadline = time.monotonic() + 120
    while not (table.exists() and table.read_text().count("\n") >= 6):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.05)
    returncode, stderr = stop(proc, sig)
    assert returncode == code, stderr
    assert stderr == f"fusion-pf: terminated by signal {int(sig)}\n"
    assert check_outputs(out, table) >= 5


@pytest.mark.parametrize("when", ["handler installed", "0.3 s"])
@pytest.mark.parametrize("sig, code", SIGNALS)
def test_track_stops_cleanly_on_a_signal_during_start_up(tmp_path, sig, code, when):
    proc, out, table = start_track(tmp_path)
    started = time.monotonic()
    while not handles(proc.pid, sig):  # before, the interpreter is starting: the signal's default action ends it
        assert proc.poll() is None and time.monotonic() - started < 60
        time.sleep(0.001)
    if when == "0.3 s":
        time.sleep(max(0.0, 0.3 - (time.monotonic() - started)))
    returncode, stderr = stop(proc, sig)
    assert returncode == code, stderr
    assert stderr == f"fusion-pf: terminated by signal {int(sig)}\n"
    if out.exists():  # stopped after the outputs were opened: they are complete
        check_outputs(out, table)


#: Calls ``cli.main`` once per statement of :mod:`fusion_pf.cli` and :mod:`fusion_pf.signals` it runs, sending SIGHUP
#: to itself just before that statement (while Python handles SIGHUP), and prints each run's injection point, exit
#: status and stderr as JSON. CI's ``handler installed`` run once hit the statement between the handler's
#: installation and the command's ``try``, and stopped with 129 and no line.
_STOP_AT_EVERY_STATEMENT = """
import io, json, os, signal, sys
from fusion_pf import cli, signals

watched = {cli.__file__, signals.__file__}
argv = ["info", sys.argv[1]]
cli.main(argv)  # the commands imported once, outside the count
for n in range(1, 10000):
    seen, sent = [0], []

    def tracer(frame, event, arg):
        if frame.f_code.co_filename not in watched:
            return None
        if event == "line":
            seen[0] += 1
            if seen[0] == n and callable(signal.getsignal(signal.SIGHUP)):
                sent.append(f"{os.path.basename(frame.f_code.co_filename)}:{frame.f_lineno}")
                os.kill(os.getpid(), signal.SIGHUP)
        return tracer

    sys.stderr, err = io.StringIO(), sys.stderr
    sys.settrace(tracer)
    try:
        code = cli.main(argv)
    finally:
        sys.settrace(None)
        sys.stderr, text = err, sys.stderr.getvalue()
    print(json.dumps({"at": sent[0] if sent else None, "code": code, "stderr": text}), flush=True)
    if seen[0] < n:
        break
"""


def test_a_stop_at_any_statement_of_the_command_line_exits_129_with_one_line(tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", _STOP_AT_EVERY_STATEMENT, str(tmp_path / "missing.mcap")],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    runs = [json.loads(line) for line in done.stdout.splitlines()]
    stopped = [r for r in runs if r["at"] is not None]
    assert len(stopped) > 20, runs  # the injection reached the statements around the command
    assert {r["at"].split(":")[0] for r in stopped} == {"cli.py", "signals.py"}
    for r in stopped:
        lines = r["stderr"].splitlines()
        assert r["code"] == 129 and lines[-1] == "fusion-pf: terminated by signal 1", r
        assert lines.count("fusion-pf: terminated by signal 1") == 1 and "Traceback" not in r["stderr"], r
    for r in runs:
        if r["at"] is None:  # past the last statement that handles SIGHUP: the command's own error
            assert r["code"] == 2 and r["stderr"].startswith("fusion-pf: error: recording not found"), r


#: A Dask request still being served when a stop closes the local cluster: its asyncio task fails (the scheduler's
#: ``scatter`` raised KeyError of a worker's address already removed, seen in
#: ``test_a_stop_during_the_sweep_leaves_no_traceback``) and is collected after the stop, unretrieved.
_UNRETRIEVED_AFTER_STOP = """
import asyncio, gc
from fusion_pf.experiments.sweep import dask_client
from fusion_pf.signals import Terminated

async def scatter():
    raise KeyError("tcp://127.0.0.1:1")

loop = asyncio.new_event_loop()
try:
    with dask_client(1, None, 1):
        task = loop.create_task(scatter())
        loop.run_until_complete(asyncio.sleep(0.01))
        raise Terminated(15)
except KeyboardInterrupt:
    pass
del task
gc.collect()
loop.close()
print("stopped")
"""


def test_a_request_failing_as_the_cluster_closes_on_a_stop_prints_no_traceback():
    """The stop is the caller's to report: asyncio's "Task exception was never retrieved" of a task the closing
    cluster left behind is not printed, whenever the task is collected."""
    done = subprocess.run(
        [sys.executable, "-c", _UNRETRIEVED_AFTER_STOP], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0 and done.stdout == "stopped\n", done.stderr
    assert "Traceback" not in done.stderr and "never retrieved" not in done.stderr, done.stderr


@pytest.mark.parametrize("after", [0.5, 2.0])
def test_a_stop_during_the_sweep_leaves_no_traceback(tmp_path, after):
    """``demo``'s Dask cluster is closed, not left half-started for an atexit traceback."""
    rec = tmp_path / "gt.mcap"
    subprocess.run(
        [*CLI, "synth", str(rec), "--frames", "60", "--size", "160x100", "--no-progress"], check=True, timeout=120
    )
    proc = subprocess.Popen(
        [*CLI, "demo", "--recording", str(rec), "--out", str(tmp_path / "demo"), "--workers", "2", "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    assert proc.stderr is not None
    lines = [proc.stderr.readline() for _ in range(2)]
    assert lines[1].startswith("demo: tracking again"), lines
    time.sleep(after)
    returncode, rest = stop(proc, signal.SIGTERM)
    assert returncode == 143 and rest.endswith("fusion-pf: terminated by signal 15\n"), rest
    assert "Traceback" not in rest, rest
