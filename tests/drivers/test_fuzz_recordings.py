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
    truth = campaign.truth_of(base, 2)
    rng = np.random.default_rng(14)
    outcomes: Counter = Counter()
    previous = signal.signal(signal.SIGALRM, _alarm)
    started = time.monotonic()
    try:
        for k in range(MUTATIONS):
            what, mutated = campaign.mutate(data, rng, truth)
            path = tmp_path / f"m{k % 4}.mcap"
            path.write_bytes(mutated)
            for name, check in (("replay", campaign.check_replay), ("info", campaign.check_info)):
                signal.setitimer(signal.ITIMER_REAL, SECONDS_PER_CHECK)
                try:
                    result = check(str(path), truth)
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


def test_damage_before_and_inside_the_background_section_is_never_silent_in_track(tmp_path, make_frames, record):
    """Issue 24 item 4: byte ranges removed before and inside the background section, through ``fusion-pf track``.

    Every person frame the file still holds is tracked under its own number, and
    every other frame is reported (the oracle identifies frames by timestamp).
    """
    campaign = _load_campaign()
    frames = make_frames(16, background=6)
    base = record(tmp_path / "base.mcap", frames, chunk_size=20_000, metadata={"background_frames": "6"})
    truth = campaign.truth_of(base, 6)
    data = base.read_bytes()
    rng = np.random.default_rng(24)
    outcomes: Counter = Counter()
    for k in range(16):
        kinds = ("remove-before-background", "remove-in-background")
        what, mutated = campaign.mutate(data, rng, truth, kinds)
        path = tmp_path / f"b{k % 2}.mcap"
        path.write_bytes(mutated)
        for name, check in (("replay", campaign.check_replay), ("track", campaign.check_track)):
            result = check(str(path), truth)
            outcomes[name, result["class"]] += 1
            assert result["class"] in ALLOWED, (what, name, result)
            assert not result.get("misnumbered"), (what, name, result)
    assert outcomes["track", "ok-with-report"] >= 8, outcomes
