"""drivers/live.py helpers: ``--realtime`` pacing, the live status line, addresses."""

import io
import time

import pytest

from drivers import open_source
from drivers.live import LiveOptions, LiveStatus, paced, parse_address
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
