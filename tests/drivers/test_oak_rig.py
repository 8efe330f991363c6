"""Several OAK cameras (``oak:device=ID1+ID2``): matching, per-device pipelines, the rig recording, no device.

No camera is attached here. The device-independent parts run for real: each
device's pipeline is built by the driver on its own stand-in ``dai.Pipeline(device)``
(:mod:`dai_spec`, calls checked against the installed depthai) whose Sync node is a
real depthai host node; real ``ImgFrame`` messages go through it, the frames of
the devices are matched by :class:`drivers.oak_rig.RigSync`, written by
``fusion-pf record`` (:class:`drivers.rig.RigRecorder`) and read back by
:class:`drivers.rig.RigReplay`. The no-device path runs on the real depthai.
"""

from __future__ import annotations

import datetime
import itertools
import re
import subprocess
import sys
import threading
from pathlib import Path

import depthai as dai
import numpy as np
import pytest

from drivers import is_rig_spec, open_rig, open_source
from drivers.oak import NO_DEVICE_MESSAGE
from drivers.oak_rig import IDENTITY_WARNING, OakRig, RigSync, camera_name
from drivers.rig import RigReplay, extrinsics_document, load_extrinsics, write_extrinsics
from fusion_pf import cli
from fusion_pf.errors import DeviceError, InputError
from fusion_pf.frame import Frame, Intrinsics
from fusion_pf.rig import CameraPose

from .dai_spec import REAL_DEVICE, REAL_PIPELINE, SpecDevice, SpecPipeline, check_call
from .test_oak_open import H, W, _answers, _depth, _transformation

PERIOD = 33_333_333
TOL = PERIOD // 2
K = Intrinsics(8, 6, 6.0, 6.0, 3.5, 2.5)


def _frame(t: int, seq: int = 0) -> Frame:
    return Frame(t, seq, np.full((6, 8, 3), seq % 256, np.uint8), None, K)


# --------------------------------------------------------------------------- matching


def _run(sync: RigSync, arrivals: list[tuple[str, int]]) -> list[tuple[int, dict[str, int]]]:
    """Push ``(camera, t)`` arrivals, end every camera; the instants as ``(t, {camera: original seq})``."""
    out = []
    for camera, t in arrivals:
        out += sync.push(camera, _frame(t, seq=t // 1_000_000))
    out += sync.flush()
    for t, frames in out:
        assert all(f.timestamp_ns == t for f in frames.values())
    return [(t, {c: f.seq for c, f in frames.items()}) for t, frames in out]


def test_frames_within_half_a_period_form_one_instant_whatever_the_arrival_order() -> None:
    a = [1_000_000_000 + k * PERIOD for k in range(6)]
    b = [t + 4_000_000 for t in a]  # 4 ms later
    del b[3]  # camera b lost one frame
    c = [t - 9_000_000 for t in a[1:]]  # started late, 9 ms earlier
    streams = {"a": a, "b": b, "c": c}
    expected = None
    # per camera in time order; across cameras every interleaving of these three orders
    orders = [
        [(cam, t) for cam in ("a", "b", "c") for t in streams[cam]],
        [(cam, t) for cam in ("c", "b", "a") for t in streams[cam]],
        [
            (cam, t)
            for trio in itertools.zip_longest(*[[(n, t) for t in streams[n]] for n in ("b", "a", "c")])
            for cam, t in filter(None, trio)
        ],
    ]
    for arrivals in orders:
        sync = RigSync(["a", "b", "c"], TOL)
        got = _run(sync, arrivals)
        expected = expected or got
        assert got == expected
    assert expected is not None
    # instant times: the earliest frame of each instant; 6 instants, the first without c
    assert [t for t, _ in expected] == [a[0]] + [t - 9_000_000 for t in a[1:]]
    assert [sorted(f) for _, f in expected] == [["a", "b"]] + [["a", "b", "c"]] * 2 + [["a", "c"]] + [
        ["a", "b", "c"]
    ] * 2
    assert sync.instants == 6 and sync.complete == 4
    assert sync.frames == {"a": 6, "b": 5, "c": 5} and sync.unmatched == {"a": 0, "b": 0, "c": 0}


def test_a_frame_without_partner_is_written_alone_and_counted() -> None:
    sync = RigSync(["a", "b"], TOL)
    # b lost its frame near PERIOD; its last comes 20 ms after a's last (beyond 16.7 ms): each stands alone
    got = _run(sync, [("a", 0), ("a", PERIOD), ("b", 1_000_000), ("b", 2 * PERIOD + 20_000_000), ("a", 2 * PERIOD)])
    assert [(t, sorted(f)) for t, f in got] == [
        (0, ["a", "b"]),
        (PERIOD, ["a"]),
        (2 * PERIOD, ["a"]),
        (2 * PERIOD + 20_000_000, ["b"]),
    ]
    assert sync.unmatched == {"a": 2, "b": 1}
    assert sync.summary() == (
        "4 instants, 1 with every camera; a 3 frames (2 without a partner), b 2 frames (1 without a partner)"
    )


def test_instants_wait_for_a_silent_camera_until_it_ends() -> None:
    sync = RigSync(["a", "b"], TOL)
    assert sync.push("a", _frame(0)) == [] and sync.push("a", _frame(PERIOD)) == []
    ready = sync.end("b")  # b will send nothing: a's frames are decided
    assert [(t, sorted(f)) for t, f in ready] == [(0, ["a"]), (PERIOD, ["a"])]


def test_a_silent_camera_holds_back_at_most_max_wait_of_the_others_frames() -> None:
    sync = RigSync(["a", "b"], TOL, max_wait_ns=10 * PERIOD)
    ready = [r for k in range(12) for r in sync.push("a", _frame(1_000_000_000 + k * PERIOD))]
    # frame k is decided once frame k + 10 arrived: b, still silent (booting), is absent from it
    assert [(t - 1_000_000_000) // PERIOD for t, _ in ready] == [0, 1]
    assert all(list(f) == ["a"] for _, f in ready)
    # b's first frame, captured at a's frame 11: matched with it (nothing of b was dropped)
    ready = sync.push("b", _frame(1_000_000_000 + 11 * PERIOD + 2_000_000)) + sync.flush()
    assert [sorted(f) for _, f in ready][-1] == ["a", "b"] and sync.late == {"a": 0, "b": 0}
    assert RigSync(["a"], 1).max_wait_ns == 1_000_000_000


def test_a_frame_older_than_an_emitted_instant_is_dropped_and_counted() -> None:
    sync = RigSync(["a", "b"], TOL)
    sync.push("a", _frame(1_000_000_000))
    sync.push("b", _frame(1_100_000_000))  # decides the first instant (a alone)
    assert sync.push("a", _frame(999_999_995)) == []
    assert sync.late == {"a": 1, "b": 0}
    assert "a 1 frames (1 without a partner, 1 out of time order dropped)" in sync.summary()


def test_rig_sync_refuses_bad_arguments() -> None:
    with pytest.raises(InputError, match=r"distinct and at least one, got \['a', 'a'\]"):
        RigSync(["a", "a"], 1)
    with pytest.raises(InputError, match="int >= 0 .* got -1"):
        RigSync(["a"], -1)
    with pytest.raises(InputError, match="camera 'z' is not in the rig"):
        RigSync(["a"], 1).push("z", _frame(0))


# --------------------------------------------------------------------------- specs


def test_rig_specs_and_camera_names(tmp_path: Path) -> None:
    assert is_rig_spec("oak:device=14442C10D13EABCE00+192.168.1.44")
    assert not is_rig_spec("oak:device=14442C10D13EABCE00") and not is_rig_spec("synth:frames=3")
    assert is_rig_spec("oak", device="A+B")
    rig = open_rig("oak:device=14442C10D13EABCE00+192.168.1.44,fps=15,pose=none")
    assert isinstance(rig, OakRig) and rig.live
    assert rig.cameras == ("oak_14442C10D13EABCE00", "oak_192_168_1_44")
    assert all(pose == CameraPose.identity() for pose in rig.poses.values())
    assert rig.rig_notes == [IDENTITY_WARNING] and rig.tolerance_ns == 33_333_333
    assert [c.fps for c in rig.configs] == [
        15.0,
        15.0,
    ] and rig.describe() == "2 OAK cameras 640x400 @ 15 fps, pose none"
    assert camera_name("1.3") == "oak_1_3"
    cams = tmp_path / "cams.yaml"
    left = CameraPose.from_rvec([0.0, 0.3, 0.0], [-400.0, 0.0, 0.0])
    write_extrinsics(cams, extrinsics_document({"left": left, "right": CameraPose.identity()}))
    rig = open_rig("oak:device=A+B", extrinsics=cams)
    assert rig.cameras == ("left", "right") and rig.rig_notes == []
    moved, turned = rig.poses["left"].error_to(left)  # the file keeps 0.1 um and 1e-9 of a quaternion
    assert moved < 1e-3 and turned < 1e-6


@pytest.mark.parametrize(
    ("spec", "kwargs", "message"),
    [
        ("oak:device=A+A", {}, "an OAK device is named twice in device=A\\+A"),
        ("oak:device=A+", {}, "oak device must be ID or ID1\\+ID2\\+... \\(non-empty device ids\\), got 'A\\+'"),
        ("oak:device=A+B,fps=99", {}, "oak fps must be in \\[1, 60\\], got 99"),
        ("oak:device=A+B+C", {"three": True}, "the extrinsics name 2 camera\\(s\\) \\(left, right\\) but 3 OAK"),
        ("oak:device=A", {"three": True}, "several OAK cameras need two or more device ids"),
    ],
)
def test_bad_rig_specs_are_one_line_errors(tmp_path: Path, spec: str, kwargs: dict, message: str) -> None:
    overrides = {}
    if kwargs:
        cams = tmp_path / "cams.yaml"
        write_extrinsics(cams, extrinsics_document({"left": CameraPose.identity(), "right": CameraPose.identity()}))
        overrides["extrinsics"] = cams
    with pytest.raises(InputError, match=message):
        open_rig(spec, **overrides)


def test_a_single_camera_reader_refuses_a_rig_spec_with_one_line() -> None:
    with pytest.raises(InputError, match=r"names several cameras: record them with fusion-pf record oak:device=A\+B"):
        open_source("oak:device=A+B")


# --------------------------------------------------------------------------- no camera attached


def test_cli_record_of_several_cameras_without_any_device_exits_2_with_one_line(tmp_path: Path) -> None:
    out = tmp_path / "rig.mcap"
    proc = subprocess.run(
        [sys.executable, "-m", "fusion_pf", "record", "oak:device=14442C10D13EABCE00+18443010B1F4C81200", str(out)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if not re.match(r"^\[[^\]]+\] \[depthai\]", line)]
    assert lines == [f"fusion-pf: error: {NO_DEVICE_MESSAGE}"]
    assert not out.exists()


def test_cli_track_of_several_cameras_is_refused_with_one_line(tmp_path: Path, capsys) -> None:
    status = cli.main(["track", "oak:device=A+B", "-o", str(tmp_path / "t.mcap")])
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "fusion-pf: error: oak:device=A+B names several cameras: record them with fusion-pf record "
        "oak:device=A+B OUT.mcap; tracking several cameras at once is not built yet"
    ]


# --------------------------------------------------------------------------- per-device pipelines, host-only

IDS = ("14442C10D13EABCE00", "18443010B1F4C81200")


@pytest.fixture()
def two_devices(monkeypatch: pytest.MonkeyPatch):
    """Two stand-in devices (ids :data:`IDS`) on the depthai module; returns (devices, pipelines by device id)."""
    infos = []
    for k, device_id in enumerate(IDS):
        info = dai.DeviceInfo(device_id)
        info.name = f"1.{k + 3}"
        infos.append(info)
    devices = {device_id: SpecDevice(_answers()) for device_id in IDS}
    pipelines: dict[str, SpecPipeline] = {}

    class Device:
        @staticmethod
        def getAllAvailableDevices() -> list:
            return list(infos)

        def __new__(cls, arg):
            check_call(REAL_DEVICE, "__init__", (arg,), {})
            return devices[arg.getDeviceId()]

    def pipeline(arg=True):
        check_call(REAL_PIPELINE, "__init__", (arg,), {})
        (device_id,) = [i for i, d in devices.items() if d is arg]
        built = SpecPipeline()
        pipelines[device_id] = built
        return built

    monkeypatch.setattr(dai, "Device", Device)
    monkeypatch.setattr(dai, "Pipeline", pipeline)
    return devices, pipelines


def _colour(seq: int, offset_ms: int) -> dai.ImgFrame:
    rng = np.random.default_rng(seq)
    frame = dai.ImgFrame()
    frame.setCvFrame(rng.integers(0, 256, (H, W, 3), dtype=np.uint8), dai.ImgFrame.Type.BGR888i)
    frame.setTransformation(_transformation())
    frame.setSequenceNum(seq)
    frame.setTimestamp(datetime.timedelta(seconds=100, milliseconds=33 * seq + offset_ms))
    return frame


def _depth_at(seq: int, offset_ms: int) -> dai.ImgFrame:
    frame = _depth(seq)
    frame.setTimestamp(datetime.timedelta(seconds=100, milliseconds=33 * seq + offset_ms))
    return frame


def test_record_two_devices_into_one_rig_recording(two_devices, tmp_path: Path, capsys) -> None:
    devices, pipelines = two_devices
    cams = tmp_path / "cams.yaml"
    right = CameraPose.from_rvec([0.0, -0.4, 0.0], [500.0, 0.0, 100.0])
    write_extrinsics(cams, extrinsics_document({"left": CameraPose.identity(), "right": right}))
    out = tmp_path / "rig.mcap"
    sent = {IDS[0]: [0, 1, 2, 3, 4, 5, 6], IDS[1]: [0, 1, 3, 4, 5, 6]}  # device 2 lost frame 2
    offsets = {IDS[0]: 0, IDS[1]: 5}  # device 2's frames 5 ms later
    started = threading.Event()

    def feed() -> None:
        started.wait(30)
        for device_id, seqs in sent.items():
            feeds = pipelines[device_id].feeds
            for seq in seqs:
                feeds["inputs['colour']"].send(_colour(seq, offsets[device_id]))
                feeds["inputs['depth']"].send(_depth_at(seq, offsets[device_id]))

    original_start = SpecPipeline.start

    def start(self, *args, **kwargs):
        original_start(self, *args, **kwargs)
        if len(pipelines) == 2 and all(any(c.name == "start" for c in p.calls) for p in pipelines.values()):
            started.set()

    SpecPipeline.start = start  # type: ignore[method-assign]
    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    try:
        status = cli.main(
            [
                "record",
                "oak:device=" + "+".join(IDS) + ",pose=none",
                str(out),
                "--extrinsics",
                str(cams),
                "--frames",
                "6",
            ]
        )
    finally:
        SpecPipeline.start = original_start  # type: ignore[method-assign]
    feeder.join(5)
    captured = capsys.readouterr()
    assert status == 0, captured.err
    # one pipeline per device, each built on its device and stopped and closed once
    assert sorted(pipelines) == sorted(IDS)
    for device_id, pipe in pipelines.items():
        assert [c.name for c in pipe.calls].count("stop") == 1
        assert [c.name for c in devices[device_id].calls].count("close") == 1
        assert len(pipe.of(dai.node.Sync)) == 1 and len(pipe.of(dai.node.StereoDepth)) == 1
    assert "recorded 6 instants of 2 cameras" in captured.out
    assert "matching: " in captured.out and "left 6 frames (1 without a partner)" in captured.out
    assert "right 5 frames (0 without a partner)" in captured.out
    assert "camera left: colour intrinsics from the first frame" in captured.err
    with RigReplay(out) as rig:
        assert rig.cameras == ("left", "right")
        assert rig.poses["right"] == load_extrinsics(cams)["right"] and rig.poses["left"] == CameraPose.identity()
        sets = list(rig)
        meta = rig.replays["left"].metadata()
    assert [sorted(s.views) for s in sets] == [["left", "right"]] * 2 + [["left"]] + [["left", "right"]] * 3
    steps = np.diff([s.timestamp_ns for s in sets])
    assert (steps == 33_000_000).all()  # left's clock: the earliest frame of each instant
    for s in sets:
        seqs = {name: v.frame.seq for name, v in s.views.items()}
        assert len(set(seqs.values())) == 1  # the same capture instant on both devices
        np.testing.assert_array_equal(s.views["left"].frame.depth, _depth(s.views["left"].frame.seq).getFrame())
    assert meta["oak_devices"] == ",".join(IDS) and meta["oak_rig_poses"] == "extrinsics file"
    assert meta["right/oak_device_id"] == IDS[1] and meta["oak_rig_tolerance_ns"] == "16666667"
    # one clock for every device: the offset taken once
    assert meta["left/oak_wall_offset_ns"] == meta["right/oak_wall_offset_ns"]


def test_a_missing_device_id_is_named_and_nothing_is_opened(two_devices) -> None:
    devices, pipelines = two_devices
    with pytest.raises(DeviceError) as info:
        with open_rig(f"oak:device={IDS[0]}+XYZ"):
            pytest.fail("opened a rig with a device that is not there")
    assert str(info.value) == (f"camera oak_XYZ: OAK device 'XYZ' not found; available: {IDS[0]} (1.3), {IDS[1]} (1.4)")
    assert pipelines == {} and all(not d.calls for d in devices.values())


def test_a_device_failing_to_start_closes_the_ones_already_open(two_devices) -> None:
    devices, pipelines = two_devices
    devices[IDS[1]].answers["readCalibration"] = RuntimeError("EEPROM\nempty")
    with pytest.raises(DeviceError) as info:
        open_rig("oak:device=" + "+".join(IDS) + ",pose=none").open()
    assert str(info.value) == (
        f"camera oak_{IDS[1]} (device {IDS[1]}): OAK device {IDS[1]} failed to start the pipeline: EEPROM empty"
    )
    assert [c.name for c in devices[IDS[0]].calls].count("close") == 1
    assert [c.name for c in pipelines[IDS[0]].calls].count("stop") == 1


def test_a_device_lost_mid_recording_keeps_every_frame_and_names_the_camera(
    two_devices, tmp_path: Path, capsys
) -> None:
    devices, pipelines = two_devices
    out = tmp_path / "rig.mcap"
    started = threading.Event()

    def feed() -> None:
        started.wait(30)
        for k, device_id in enumerate(IDS):
            feeds = pipelines[device_id].feeds
            for seq in range(5):
                feeds["inputs['colour']"].send(_colour(seq, 3 * k))
                feeds["inputs['depth']"].send(_depth_at(seq, 3 * k))
        threading.Timer(0.5, pipelines[IDS[1]].host.stop).start()  # device 2's cable pulled

    original_start = SpecPipeline.start

    def start(self, *args, **kwargs):
        original_start(self, *args, **kwargs)
        if len(pipelines) == 2 and all(any(c.name == "start" for c in p.calls) for p in pipelines.values()):
            started.set()

    SpecPipeline.start = start  # type: ignore[method-assign]
    threading.Thread(target=feed, daemon=True).start()
    try:
        status = cli.main(["record", "oak:device=" + "+".join(IDS) + ",pose=none", str(out)])
    finally:
        SpecPipeline.start = original_start  # type: ignore[method-assign]
    captured = capsys.readouterr()
    assert status == 2
    (error,) = [line for line in captured.err.splitlines() if line.startswith("fusion-pf: error:")]
    assert error.startswith(
        f"fusion-pf: error: source oak:device={'+'.join(IDS)},pose=none failed after 5 instants "
        f"(camera oak_{IDS[1]} (device {IDS[1]}): the OAK stream closed"
    )
    assert IDENTITY_WARNING in captured.err
    assert "recorded 5 instants of 2 cameras" in captured.out
    with RigReplay(out) as rig:
        sets = list(rig)
        assert rig.replays[rig.cameras[0]].metadata()["oak_rig_poses"].startswith("identity")
    assert [len(s.views) for s in sets] == [2] * 5
    for device_id in IDS:
        assert [c.name for c in devices[device_id].calls].count("close") == 1
