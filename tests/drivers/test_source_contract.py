"""One contract suite run over every replay source (docs: drivers/base.py).

Each source must: open as a context manager, yield valid frames in time order,
be re-iterable with identical output, report len(), select windows by index and
by time, and count what it yields in ``stats``.
"""

import numpy as np
import pytest

from drivers import open_source
from drivers.base import ReplaySource
from fusion_pf.errors import InputError

N = 12


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    from drivers.mcap_record import McapRecorder

    path = tmp_path_factory.mktemp("contract") / "synth.mcap"
    with open_source(f"synth:frames={N},seed=5,size=160x100,background_frames=2") as src:
        with McapRecorder(path, metadata=src.metadata()) as rec:
            for frame in src:
                rec.write(frame)
    return path


@pytest.fixture(params=["synth", "mcap"])
def source(request, recorded):
    if request.param == "synth":
        return open_source(f"synth:frames={N},seed=5,size=160x100,background_frames=2")
    return open_source(str(recorded))


def frames_equal(a, b):
    return (
        a.timestamp_ns == b.timestamp_ns
        and np.array_equal(a.color, b.color)
        and np.array_equal(a.depth, b.depth)
        and a.intrinsics == b.intrinsics
        and a.ground_truth == b.ground_truth
        and a.background == b.background
        and (dict(a.joints) if a.joints is not None else None) == (dict(b.joints) if b.joints is not None else None)
    )


def test_contract(source):
    with source as src:
        assert isinstance(src, ReplaySource) and src.live is False
        assert len(src) == N
        first = list(src)
        assert len(first) == N
        times = [f.timestamp_ns for f in first]
        assert times == sorted(times) and len(set(times)) == N
        assert [f.background for f in first] == [True, True] + [False] * (N - 2)
        assert all(f.ground_truth is not None for f in first[2:])
        again = list(src)
        assert all(frames_equal(a, b) for a, b in zip(first, again))
        window = list(src.frames(3, 7))
        assert [f.timestamp_ns for f in window] == times[3:7]
        by_time = list(src.frames(start_ns=times[4], end_ns=times[9]))
        assert [f.timestamp_ns for f in by_time] == times[4:9]
        assert src.stats.frames == 2 * N


def test_synth_and_replay_agree(recorded):
    with open_source(f"synth:frames={N},seed=5,size=160x100,background_frames=2") as a, open_source(str(recorded)) as b:
        for fa, fb in zip(a, b):
            assert frames_equal(fa, fb)


@pytest.mark.parametrize(
    "spec, message",
    [
        ("webcam", "unknown source 'webcam'"),
        ("synth:frames", "source option 'frames' in 'synth:frames' must look like key=value"),
    ],
)
def test_open_source_errors(spec, message):
    with pytest.raises(InputError, match=message):
        open_source(spec)


def test_iterating_outside_with_is_an_error():
    src = open_source("synth:frames=2,size=64x48")
    with pytest.raises(RuntimeError, match="inside a 'with' block"):
        next(iter(src))
