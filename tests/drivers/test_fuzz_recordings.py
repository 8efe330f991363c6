"""Issue 14: seeded fuzz of a small recording through ``McapReplay`` and ``fusion-pf info --verify``.

A few hundred mutations (truncation, bit flips, zeroed blocks, removed and
duplicated byte ranges, junk appended; ``benchmarks/fuzz_recordings.py``
makes them) of a 12-frame recording. Every outcome must be one of: all
frames read; frames lost but every one of them reported (counted, or a
truncated tail); refused with a one-line error (exit 2). Never a traceback,
never a hang (each check has a time limit), never a frame missing silently.
"""

from __future__ import annotations

import importlib.util
import signal
import time
from collections import Counter
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "fuzz_recordings.py"
MUTATIONS = 300
SECONDS_PER_CHECK = 10
ALLOWED = {"ok", "ok-with-report", "refused-one-line"}


def _load_campaign():
    spec = importlib.util.spec_from_file_location("fuzz_recordings", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class _Hang(Exception):
    pass


def _alarm(_signum, _frame):
    raise _Hang


def test_mutated_recordings_never_lose_frames_silently(tmp_path, make_frames, record):
    campaign = _load_campaign()
    frames = make_frames(12)
    base = record(tmp_path / "base.mcap", frames, chunk_size=20_000)
    data = base.read_bytes()
    rng = np.random.default_rng(14)
    outcomes: Counter = Counter()
    previous = signal.signal(signal.SIGALRM, _alarm)
    started = time.monotonic()
    try:
        for k in range(MUTATIONS):
            what, mutated = campaign.mutate(data, rng)
            path = tmp_path / f"m{k % 4}.mcap"
            path.write_bytes(mutated)
            for name, check in (("replay", campaign.check_replay), ("info", campaign.check_info)):
                signal.setitimer(signal.ITIMER_REAL, SECONDS_PER_CHECK)
                try:
                    result = check(str(path), len(frames))
                except _Hang:
                    result = {"class": "hang"}
                finally:
                    signal.setitimer(signal.ITIMER_REAL, 0)
                outcomes[name, result["class"]] += 1
                assert result["class"] in ALLOWED, (what, name, result)
    finally:
        signal.signal(signal.SIGALRM, previous)
    elapsed = time.monotonic() - started
    assert elapsed < 60, elapsed
    # the mutations reach every outcome that is allowed, so the oracle is exercised
    assert {c for (_n, c) in outcomes} == ALLOWED, outcomes
