"""drivers/live.py helpers: ``--realtime`` pacing, the live status line, addresses."""

import io
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import rerun as rr

from drivers import open_source
from drivers.live import LiveOptions, LiveStatus, RerunLogger, _Item, paced, parse_address
from fusion_pf.errors import InputError
from fusion_pf.pipeline import TrackConfig, track


def test_paced_yields_each_frame_no_earlier_than_its_timestamp():
    with open_source("synth:seed=1,frames=12,size=320x200") as src:
        frames = list(src)
    span = (frames[-1].timestamp_ns - frames[0].timestamp_ns) / 1e9
    t0 = time.perf_counter()
    seen, out = [], []
    for f in paced(frames):
        seen.append((time.perf_counter() - t0, (f.timestamp_ns - frames[0].timestamp_ns) / 1e9))
        out.append(f)
    assert out == frames
    assert all(wall >= ts - 1e-3 for wall, ts in seen)
    assert seen[-1][0] >= span - 1e-3


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("tty", [True, False])
def test_the_status_line_shows_fps_state_and_the_palm_in_px_and_mm(tty):
    stream = _Tty() if tty else io.StringIO()
    status = LiveStatus(stream)
    with open_source("synth:seed=1,frames=4,size=320x200") as src:
        for result in track(src, TrackConfig()):
            status.update(result)
            time.sleep(0.11)
    status.close()
    text = stream.getvalue()
    e = result.estimate
    assert f"palm ({e.u:.0f}, {e.v:.0f}) px" in status.line(result)
    assert "({:.0f}, {:.0f}, {:.0f}) mm".format(*result.xyz_mm) in status.line(result)
    if tty:  # rewritten in place, several times, ended by a newline
        assert text.count("\r\x1b[K") >= 3 and text.endswith("\n") and "fps  tracking" in text
    else:  # one line now and then
        assert text.count("\n") == 1 and "\r" not in text


@pytest.mark.parametrize(
    ("text", "expected"),
    [("8765", ("127.0.0.1", 8765)), ("0.0.0.0:1", ("0.0.0.0", 1)), ("[::1]:9000", ("::1", 9000))],
)
def test_parse_address(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize("text", ["host:", "http", "1:70000", ":80"])
def test_bad_addresses_are_refused(text):
    with pytest.raises(InputError):
        parse_address(text)


def test_loopback_needs_no_flag_and_other_hosts_do():
    assert LiveOptions(serve="localhost:8765").serve == "localhost:8765"
    assert LiveOptions(serve="[::1]:8765").serve == "[::1]:8765"
    with pytest.raises(InputError, match="--allow-remote"):
        LiveOptions(serve="10.0.0.2:8765")
    assert LiveOptions(serve="10.0.0.2:8765", allow_remote=True).serve == "10.0.0.2:8765"


def test_the_status_line_of_several_targets_shows_each_target_state_and_px():
    status = LiveStatus(io.StringIO())
    config = TrackConfig(targets=("right_hand", "left_hand"))
    with open_source("synth:seed=1,frames=4,size=320x200,hands=2") as src:
        result = list(track(src, config))[-1]
    line = status.line(result)
    for t in ("right_hand", "left_hand"):
        r = result.targets[t]
        px = "-" if r.estimate is None else f"({r.estimate.u:.0f}, {r.estimate.v:.0f}) px"
        assert f"{t} {r.state} {px}" in line
    assert any(r.estimate is not None for r in result.targets.values())


def test_rerun_gets_every_target_estimate_labelled_by_target_and_state(tmp_path):
    """The Rerun logger of several targets, saved to an .rrd and read back by Rerun's own ``rerun rrd print``."""
    config = TrackConfig(targets=("right_hand", "left_hand"))
    with open_source("synth:seed=1,frames=4,size=320x200,hands=2") as src:
        results = list(track(src, config))
    logger = RerunLogger("rerun+http://127.0.0.1:9876/proxy")
    logger.rec = rr.RecordingStream("fusion-pf")  # the viewer replaced by a file
    logger.rec.save(tmp_path / "live.rrd")
    for r in results:
        logger.publish(_Item(r.source_frame, [], r))
    logger.close()
    env = {**os.environ, "HOME": str(tmp_path), "RERUN_TELEMETRY_ENABLED": "false"}
    rerun = Path(sys.executable).parent / "rerun"
    text = subprocess.run(
        [str(rerun), "rrd", "print", "-vvv", str(tmp_path / "live.rrd")], env=env, capture_output=True, text=True
    ).stdout
    for r in results:
        labels = ", ".join(f"{t} {x.state}" for t, x in r.targets.items() if x.estimate is not None)
        assert labels and f"[{labels}]" in text
    assert "[right_hand, left_hand]" in text  # the 3-D palms
