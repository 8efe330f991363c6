"""OAK source options, device selection, pose-model resolution and the no-device path.

This machine has no OAK camera, so the no-device path runs for real.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import depthai as dai
import pytest

from drivers import open_source
from drivers.oak import NO_DEVICE_MESSAGE, OakConfig, OakSource, select_device
from drivers.oak_pipeline import BUILTIN_POSE_MODELS, builtin_model_path, resolve_pose_model
from fusion_pf.errors import DeviceError, InputError


def test_defaults() -> None:
    config = OakConfig()
    assert (config.size, config.fps, config.pose, config.device, config.timeout_s) == (
        (640, 400),
        30.0,
        "lightning",
        None,
        3.0,
    )


def test_spec_options_and_typed_overrides() -> None:
    src = open_source("oak:size=1280x800,fps=15,pose=thunder,device=192.168.1.44,timeout=5")
    assert isinstance(src, OakSource) and src.live
    assert src.config == OakConfig((1280, 800), 15.0, "thunder", "192.168.1.44", 5.0)
    # what `record --size/--fps` forwards as keyword overrides
    src = open_source("oak:fps=15", size=(1280, 720), fps=20)
    assert (src.config.size, src.config.fps) == ((1280, 720), 20.0)
    src = open_source("oak", size="320x240")
    assert src.config.size == (320, 240)
    assert src.describe() == "OAK camera 320x240 @ 30 fps, pose lightning"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"size": "640"}, "oak size must look like WIDTHxHEIGHT .* got '640'"),
        ({"size": "650x400"}, r"width must be a multiple of 16 in \[160, 1920\], got 650"),
        ({"size": "640x401"}, r"height must be even and in \[120, 1200\], got 401"),
        ({"size": (640.0, 400)}, "oak size must be 'WxH' or"),
        ({"fps": "fast"}, "oak fps must be a number, got 'fast'"),
        ({"fps": "0.5"}, r"oak fps must be in \[1, 60\], got 0.5"),
        ({"timeout": "0"}, r"oak timeout must be in \(0, 60\] seconds, got 0"),
        ({"pose": "posenet"}, "oak pose must be lightning, thunder, none, .* got 'posenet'"),
        (
            {"duration": "10"},
            "unknown oak option.* duration; expected: size, fps, pose, device, timeout, ir_laser, hands",
        ),
        ({"ir_laser": "5000"}, r"oak ir_laser must be in \[0, 1200\] mA, got 5000"),
        (
            {"hands": "huge"},
            r"hands must be none, lite, full, sparse \(RVC2 blobs\), zoo or PALM.tar.xz\+LANDMARKS.tar.xz "
            r"\(NN archives\), got 'huge'",
        ),
        ({"device": ""}, "oak device must be a non-empty"),
    ],
)
def test_bad_options_name_value_and_range(options: dict, message: str) -> None:
    with pytest.raises(InputError, match=message):
        OakSource.from_options(options)


def test_no_device_is_a_fast_one_line_device_error() -> None:
    assert dai.Device.getAllAvailableDevices() == [], "this test expects no OAK device attached"
    start = time.monotonic()
    with pytest.raises(DeviceError) as info:
        with open_source("oak"):
            pytest.fail("opened a device that is not there")
    assert time.monotonic() - start < 3.0
    assert str(info.value) == NO_DEVICE_MESSAGE
    assert "\n" not in NO_DEVICE_MESSAGE
    assert "fusion-pf track recordings/sample.mcap -o out.mcap" in NO_DEVICE_MESSAGE  # a command that works


def test_iterating_without_with_is_refused() -> None:
    with pytest.raises(RuntimeError, match="must be used inside a 'with' block"):
        next(iter(OakSource()))


def _info(device_id: str, name: str) -> dai.DeviceInfo:
    info = dai.DeviceInfo(device_id)
    info.name = name
    return info


def test_select_device() -> None:
    usb = _info("14442C10D13EABCE00", "1.3")
    poe = _info("18443010B1F4C81200", "192.168.1.44")
    assert select_device([usb, poe], None) is usb
    assert select_device([usb, poe], "192.168.1.44") is poe
    assert select_device([usb, poe], "14442C10D13EABCE00") is usb
    with pytest.raises(
        DeviceError, match=r"'XYZ' not found; available: 14442C10D13EABCE00 \(1.3\), 18443010B1F4C81200"
    ):
        select_device([usb, poe], "XYZ")
    with pytest.raises(DeviceError, match="no OAK device found"):
        select_device([], "XYZ")


@pytest.mark.parametrize(("name", "size"), [("lightning", (192, 192)), ("thunder", (256, 256))])
def test_builtin_movenet_blobs_load_offline(name: str, size: tuple[int, int]) -> None:
    model = resolve_pose_model(name, "RVC2")
    assert model is not None
    assert model.kind == "blob" and model.input_size == size and model.platforms == ("RVC2",)
    assert model.path == builtin_model_path(name)
    assert model.path.name == BUILTIN_POSE_MODELS[name]


def test_user_blob_path_and_platform_check() -> None:
    model = resolve_pose_model(str(builtin_model_path("lightning")), "RVC2")
    assert model is not None and model.input_size == (192, 192)
    with pytest.raises(DeviceError, match="runs on RVC2, but the connected OAK is RVC4; give pose=PATH.tar.xz"):
        resolve_pose_model("lightning", "RVC4")
    assert resolve_pose_model("none", "RVC4") is None


def test_bad_pose_models(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(InputError, match="pose model file '.*missing.blob' does not exist"):
        resolve_pose_model(str(tmp_path / "missing.blob"), "RVC2")
    junk = tmp_path / "junk.blob"
    junk.write_bytes(b"not a blob")
    with pytest.raises(InputError, match="junk.blob is not a readable OpenVINO blob"):
        resolve_pose_model(str(junk), "RVC2")
    archive = tmp_path / "junk.tar.xz"
    archive.write_bytes(b"not an archive")
    with pytest.raises(InputError, match="junk.tar.xz is not a readable NN archive"):
        resolve_pose_model(str(archive), "RVC4")
    monkeypatch.delenv("DEPTHAI_ZOO_CACHE_PATH", raising=False)
    with pytest.raises(InputError, match="pose=zoo:luxonis/x needs DEPTHAI_ZOO_CACHE_PATH"):
        resolve_pose_model("zoo:luxonis/x", "RVC2")
    with pytest.raises(InputError, match="pose must be lightning, thunder, none"):
        resolve_pose_model("model.onnx", "RVC2")
    with pytest.raises(InputError, match="built-in pose model must be one of"):
        builtin_model_path("heavy")


def test_metadata_needs_an_open_source() -> None:
    with pytest.raises(DeviceError, match="not open"):
        OakSource().metadata()


def test_cli_record_without_device_exits_2_with_one_line(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    start = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "fusion_pf", "record", "oak", str(out), "--duration", "10"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    elapsed = time.monotonic() - start
    assert proc.returncode == 2, proc.stderr
    assert elapsed < 10.0  # refused at once: never waits out --duration 10 (start-up time is a benchmark's business)
    assert not out.exists()
    lines = proc.stderr.splitlines()
    assert [line for line in lines if line.startswith("fusion-pf:")] == [f"fusion-pf: error: {NO_DEVICE_MESSAGE}"]
    # anything else is depthai's own log (e.g. its container USB warning), never a traceback
    assert all(
        re.match(r"^\[[^\]]+\] \[depthai\] \[warning\]", line) for line in lines if not line.startswith("fusion-pf:")
    )
    assert "Traceback" not in proc.stderr
    assert not out.exists()  # nothing written when there is no camera


def test_cli_ir_laser_is_validated_before_looking_for_a_device(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "fusion_pf", "record", "oak", str(tmp_path / "x.mcap"), "--ir-laser", "5000"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2
    assert "fusion-pf: error: oak ir_laser must be in [0, 1200] mA, got 5000" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_hands_option_reaches_the_config() -> None:
    src = open_source("oak:hands=full,ir_laser=250")
    assert (src.config.hands, src.config.ir_laser) == ("full", 250.0)


def test_a_native_crash_after_importing_depthai_ends_the_process_without_depthais_handler() -> None:
    # depthai's backward-cpp handler allocates inside the signal handler and deadlocked a test worker after glibc
    # aborted inside malloc (drivers/__init__.py); with it unset by importing drivers first, a crash ends the process
    # at once and no handler prints its stack trace
    code = "import drivers, depthai, ctypes; ctypes.string_at(0)"
    env = {k: v for k, v in os.environ.items() if k != "DEPTHAI_INSTALL_SIGNAL_HANDLER"}
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env, cwd=root)
    assert done.returncode == -signal.SIGSEGV
    assert "Stack trace (most recent call last)" not in done.stderr
