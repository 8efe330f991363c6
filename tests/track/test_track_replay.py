"""The warm-start replay (``--replay-frames``): the first frames of the track again, with the noise they taught."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from drivers.synth import SynthSource
from fusion_pf.frame import Intrinsics, Measurement
from fusion_pf.pipeline import CueRow, TrackConfig, extract_cues, run_filter, track

K = 25
INTR = Intrinsics(320, 200, 250.0, 250.0, 160.0, 100.0)
LATENCY = {"decode": 0, "colour": 0, "depth": 0, "skeleton": 0}


@pytest.fixture(scope="module")
def sharp_frames():
    """70 frames at 320 x 200 (10 background), the palm 40 cm in front of the body, depth the precise cue."""
    with SynthSource(frames=70, seed=5, size=(320, 200), background_frames=10, depth_noise=2.0, hand_front=0.4) as src:
        return list(src)


@pytest.fixture(scope="module")
def sharp_rows(sharp_frames):
    return extract_cues(sharp_frames, TrackConfig(replay_frames=0))


def _errors(results) -> np.ndarray:
    return np.array(
        [
            np.nan if r.estimate is None else np.hypot(r.estimate.u - r.ground_truth.u, r.estimate.v - r.ground_truth.v)
            for r in results
            if not r.background
        ]
    )


def test_the_replayed_start_is_nearer_the_palm(sharp_rows):
    """The filter starts at rest with the configured noise and lags the moving palm while the noise is
    learned; the replay runs those frames again with the learned noise. Measured over seeds 0-3, first 25
    tracked frames: 1.55-1.85 px without, 0.78-0.85 with; the frames after stay within 0.2 px."""
    for seed in range(4):
        off = _errors(run_filter(sharp_rows, TrackConfig(replay_frames=0, seed=seed)))
        on = _errors(run_filter(sharp_rows, TrackConfig(replay_frames=K, seed=seed)))
        assert np.isfinite(off).all() and np.isfinite(on).all()
        first_off, first_on = np.sqrt(np.mean(off[:K] ** 2)), np.sqrt(np.mean(on[:K] ** 2))
        assert first_on < 0.7 * first_off, (seed, first_on, first_off)
        assert np.sqrt(np.mean(on[K:] ** 2)) < np.sqrt(np.mean(off[K:] ** 2)) + 0.3


def test_every_frame_once_in_order_and_the_replay_only_once(sharp_rows):
    results = run_filter(sharp_rows, TrackConfig(replay_frames=K))
    assert [r.frame for r in results] == [r.frame for r in sharp_rows]
    assert all(r.state == "tracking" for r in results if not r.background)
    # a stream shorter than the replay: its frames come out at the end, replayed
    short = run_filter(sharp_rows[:20], TrackConfig(replay_frames=K))
    assert [r.frame for r in short] == [r.frame for r in sharp_rows[:20]]
    assert all(r.estimate is not None for r in short if not r.background)


def test_track_gives_the_first_frames_k_frames_late_once(sharp_frames):
    pulled = 0

    def source():
        nonlocal pulled
        for f in sharp_frames:
            pulled += 1
            yield f

    late = []
    for r in track(source(), TrackConfig(replay_frames=K, particles=60)):
        late.append(pulled - 1 - r.frame)  # frames read after this one when it came out
        assert r.source_frame is sharp_frames[r.frame]
        assert r.background or r.latency_ns["total"] > 0
    assert len(late) == len(sharp_frames)
    first = next(i for i, f in enumerate(sharp_frames) if not f.background)
    assert late[:first] == [0] * first  # background frames pass at once
    assert late[first : first + K] == list(range(K - 1, -1, -1))  # the held frames, out with the K-th
    assert set(late[first + K :]) == {0}  # then online


def test_track_and_filter_only_reruns_replay_alike(sharp_frames):
    config = TrackConfig(replay_frames=10, particles=60, seed=2)
    direct = list(track(sharp_frames, config))
    rerun = run_filter(extract_cues(sharp_frames, config), config)
    assert [(r.frame, r.state) for r in direct] == [(r.frame, r.state) for r in rerun]
    for d, r in zip(direct, rerun):
        assert (d.estimate is None) == (r.estimate is None)
        if d.estimate is not None:
            assert (d.estimate.u, d.estimate.v) == (r.estimate.u, r.estimate.v)
    off = run_filter(extract_cues(sharp_frames, config), dataclasses.replace(config, replay_frames=0))
    assert any(a.estimate.u != b.estimate.u for a, b in zip(rerun[:20], off[:20]) if a.estimate is not None)


def test_several_targets_replay_in_one_path():
    with SynthSource(frames=45, seed=4101, size=(320, 200), hands=2, background_frames=5) as src:
        frames = list(src)
    results = list(track(frames, TrackConfig(targets=("right_hand", "left_hand"), replay_frames=10, particles=60)))
    assert [r.frame for r in results] == list(range(len(frames)))
    tracked = [r for r in results if not r.background]
    assert all(set(r.targets) == {"right_hand", "left_hand"} for r in tracked)
    assert sum(r.targets["left_hand"].estimate is not None for r in tracked) > 30


def test_a_stop_while_frames_are_held_gives_them_out_first(sharp_frames):
    """A source that fails (or a signal) while the first frames are held: their rows come out, then the error."""
    from fusion_pf.errors import RecordingError

    def source():
        yield from sharp_frames[:30]
        raise RecordingError("damaged chunk")

    results = []
    with pytest.raises(RecordingError, match="damaged chunk"):
        for r in track(source(), TrackConfig(replay_frames=K, particles=60)):
            results.append(r)
    assert [r.frame for r in results] == list(range(30))
    assert sum(r.estimate is not None for r in results) == 20  # the 20 held tracked frames, replayed


def _curve_rows(
    first: dict[str, tuple[float, float] | None], n: int, seed: int, quality: float = 0.9
) -> tuple[list[CueRow], np.ndarray]:
    """A palm moving on a curve at 320 x 200, each cue 1.5 px noisy and of quality 0.9; in the first frame the
    sources of ``first`` are displaced by their offset with ``quality`` (None: no measurement)."""
    rng = np.random.default_rng(seed)
    rows, truth = [], []
    for k in range(n):
        u, v = 160.0 + 40.0 * math.sin(k / 25.0), 100.0 + 20.0 * math.cos(k / 30.0)
        cues: dict[str, Measurement | None] = {}
        for s in ("colour", "depth", "skeleton"):
            off = first.get(s, (0.0, 0.0)) if k == 0 else (0.0, 0.0)
            q = quality if k == 0 and s in first else 0.9
            cues[s] = (
                None
                if off is None
                else Measurement(s, u + off[0] + rng.normal(0, 1.5), v + off[1] + rng.normal(0, 1.5), q)
            )
        rows.append(CueRow(k, 1_000_000_000 + k * 33_333_333, False, cues, LATENCY, None, None, (0, 0), INTR))
        truth.append((u, v))
    return rows, np.array(truth)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_replay_starts_at_the_cue_the_later_frames_agree_with(seed):
    """First frame: depth (the most trusted by its configured noise) 50 px off, the skeleton on the palm, no
    colour: nothing agrees, so the first pass starts at depth. The replay's anchor is a backward pass's estimate
    of that frame, which all the later frames put on the palm: it starts at the skeleton (main: at the first
    pass's estimate, depth, 50 px off)."""
    rows, truth = _curve_rows({"depth": (50.0, 0.0), "colour": None}, 40, seed)
    first = run_filter(rows, TrackConfig(replay_frames=K, seed=seed))[0]
    assert first.estimate is not None
    assert math.hypot(first.estimate.u - truth[0, 0], first.estimate.v - truth[0, 1]) < 6.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_replay_holds_a_frame_whose_cues_all_miss_the_palm(seed):
    """First frame: depth and the skeleton agree 50 px off the palm, both doubtful (quality 0.4: no jump the
    filter would follow, ``JUMP_MIN_QUALITY``), no colour (main: tracked there, 50 px off). No cue lies near the
    backward pass's estimate of that frame: it stays uninitialised; the next starts on the palm."""
    rows, truth = _curve_rows({"depth": (50.0, 0.0), "skeleton": (50.0, 0.0), "colour": None}, 40, seed, 0.4)
    results = run_filter(rows, TrackConfig(replay_frames=K, seed=seed))
    assert results[0].estimate is None and results[0].state == "uninitialised"
    e = results[1].estimate
    assert e is not None and math.hypot(e.u - truth[1, 0], e.v - truth[1, 1]) < 6.0
    assert all(r.state == "tracking" for r in results[1:])
