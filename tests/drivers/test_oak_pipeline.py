"""Every device-pipeline variant, built node by node against the installed depthai.

depthai 3 cannot create Camera / StereoDepth / NeuralNetwork nodes without a
device, so the pipeline is built on :class:`dai_spec.SpecPipeline`: each call is
matched against the installed depthai's pybind11 signatures, ImageManip / Sync
/ ImageAlign also run on real host nodes, and config objects are depthai's own.
"""

from __future__ import annotations

import datetime
import io
import json
import tarfile
from pathlib import Path

import depthai as dai
import pytest

from drivers.oak_hands import resolve_hand_models
from drivers.oak_pipeline import (
    STEREO_INPUT_SIZE,
    SYNC_INPUTS,
    build_device_pipeline,
    builtin_model_path,
    check_platform,
    check_stream_limits,
    resolve_pose_model,
    stream_bytes_per_s,
    usb_warning,
)
from fusion_pf.errors import DeviceError, InputError

from .dai_spec import SpecPipeline, camera_features, check_call, matches

SIZE = (640, 400)
FPS = 30.0


def make_archive(path: Path, model_file: str, data: bytes, dai_type: str | None, shape: list[int], layout: str) -> Path:
    """A Luxonis NN archive (config.json + model) as luxonis' tools write it."""
    preprocessing = {"mean": [0, 0, 0], "scale": [1, 1, 1], "reverse_channels": False, "interleaved_to_planar": False}
    if dai_type is not None:
        preprocessing["dai_type"] = dai_type
    config = {
        "config_version": "1.0",
        "model": {
            "metadata": {"name": "movenet", "path": model_file, "precision": "uint8"},
            "inputs": [
                {
                    "name": "input",
                    "dtype": "uint8",
                    "input_type": "image",
                    "shape": shape,
                    "layout": layout,
                    "preprocessing": preprocessing,
                }
            ],
            "outputs": [{"name": "Identity", "dtype": "float16"}],
            "heads": [],
        },
    }
    with tarfile.open(path, "w:xz") as tar:
        for name, payload in (("config.json", json.dumps(config).encode()), (model_file, data)):
            info = tarfile.TarInfo(name)
            info.size = len(payload)
            tar.addfile(info, io.BytesIO(payload))
    return path


@pytest.fixture()
def rvc2_archive(tmp_path: Path) -> Path:
    blob = builtin_model_path("lightning").read_bytes()
    return make_archive(tmp_path / "rvc2.tar.xz", "model.blob", blob, "BGR888p", [1, 3, 192, 192], "NCHW")


@pytest.fixture()
def rvc4_archive(tmp_path: Path) -> Path:
    # a DLC archive: depthai reads the platform from the model file type; the bytes are not run
    return make_archive(tmp_path / "rvc4.tar.xz", "model.dlc", b"\0" * 64, "BGR888i", [1, 192, 192, 3], "NHWC")


def _build(platform: str, model, hands=None) -> SpecPipeline:
    pipeline = SpecPipeline()
    streams = build_device_pipeline(pipeline, platform, SIZE, FPS, model, hands)
    assert isinstance(streams.queue, dai.MessageQueue)  # the real host Sync's queue
    pipeline.streams = streams  # type: ignore[attr-defined]
    return pipeline


def _cameras(p: SpecPipeline) -> dict[str, object]:
    cams = {}
    for cam in p.of(dai.node.Camera):
        (build,) = p.calls_of(cam, "build")
        assert build.kwargs == {"sensorFps": FPS}
        cams[build.args[0].name] = cam
    return cams


def _check_common(p: SpecPipeline) -> tuple:
    cams = _cameras(p)
    assert sorted(cams) == ["CAM_A", "CAM_B", "CAM_C"]
    (colour_req,) = p.calls_of(cams["CAM_A"], "requestOutput")
    assert colour_req.args == (SIZE,)
    assert colour_req.kwargs == {
        "type": dai.ImgFrame.Type.BGR888i,
        "resizeMode": dai.ImgResizeMode.CROP,
        "fps": FPS,
        "enableUndistortion": True,
    }
    (stereo,) = p.of(dai.node.StereoDepth)
    for socket, side in (("CAM_B", "left"), ("CAM_C", "right")):
        (req,) = p.calls_of(cams[socket], "requestOutput")
        assert req.args == (STEREO_INPUT_SIZE,) and req.kwargs == {"fps": FPS}
        assert p.linked(cams[socket], "requestOutput#0", stereo, side)
    (preset,) = p.calls_of(stereo, "setDefaultProfilePreset")
    assert preset.args == (dai.node.StereoDepth.PresetMode.FAST_DENSITY,)
    config = stereo.configs["initialConfig"]  # depthai's own StereoDepthConfig
    assert config.postProcessing.temporalFilter.enable is False
    assert config.postProcessing.decimationFilter.decimationFactor == 1
    assert [c.args for c in p.calls_of(stereo, "setLeftRightCheck")] == [(True,)]
    assert [c.args for c in p.calls_of(stereo, "setSubpixel")] == [(True,)]
    assert not p.calls_of(stereo, "setOutputSize") and not p.calls_of(stereo, "setDepthAlign")
    (sync,) = p.of(dai.node.Sync)
    assert sync.shadow.runOnHost()
    sync_inputs = {name for _, _, node, name in p.links if node is sync} | {
        c.inputName for c in p.host.getConnections() if c.inputId == sync.shadow.id
    }
    assert {n.removeprefix("inputs['").removesuffix("']") for n in sync_inputs} <= set(SYNC_INPUTS)
    assert p.linked(cams["CAM_A"], "requestOutput#0", sync, "inputs['colour']")
    return cams, stereo, sync


def test_rvc2_aligns_depth_with_input_align_to() -> None:
    p = _build("RVC2", resolve_pose_model("lightning", "RVC2"))
    cams, stereo, sync = _check_common(p)
    assert p.linked(cams["CAM_A"], "requestOutput#0", stereo, "inputAlignTo")
    assert p.linked(stereo, "depth", sync, "inputs['depth']")
    assert not p.of(dai.node.ImageAlign)
    (manip,) = p.of(dai.node.ImageManip)
    (nn,) = p.of(dai.node.NeuralNetwork)
    assert p.linked(cams["CAM_A"], "requestOutput#0", manip, "inputImage")
    assert p.linked(manip, "out", nn, "input")
    assert p.linked(nn, "out", sync, "inputs['skeleton']")
    assert [c.args for c in p.calls_of(nn, "setBlobPath")] == [(builtin_model_path("lightning"),)]
    # the real ImageManip config: a 192x192 planar RGB letterbox (geaxgx's MoveNet blobs take RGB)
    manip_calls = {c.name: c.args for c in p.calls_of(manip)}
    assert manip_calls["setOutputSize"] == (192, 192, dai.ImageManipConfig.ResizeMode.LETTERBOX)
    assert manip_calls["setFrameType"] == (dai.ImgFrame.Type.RGB888p,)
    assert manip.shadow.inputImage.getBlocking() is False and manip.shadow.inputImage.getMaxSize() == 1
    assert [c.args for c in p.calls_of(nn) if c.name in ("setBlocking", "setMaxSize")] == [(False,), (1,)]
    assert abs(sync.shadow.getSyncThreshold() - datetime.timedelta(seconds=0.5 / FPS)) <= datetime.timedelta(
        microseconds=1
    )


def test_rvc4_aligns_depth_with_image_align(rvc4_archive: Path) -> None:
    model = resolve_pose_model(str(rvc4_archive), "RVC4")
    assert model.frame_type == "BGR888i"
    p = _build("RVC4", model)
    cams, stereo, sync = _check_common(p)
    (align,) = p.of(dai.node.ImageAlign)
    assert p.linked(stereo, "depth", align, "input")
    assert p.linked(cams["CAM_A"], "requestOutput#0", align, "inputAlignTo")
    # the real ImageAlign -> real Sync link, as depthai recorded it
    (conn,) = [c for c in p.host.getConnections() if c.outputName == "outputAligned"]
    assert (conn.inputName, conn.inputGroup, conn.inputId) == ("depth", "inputs", sync.shadow.id)
    assert not any(link[3] == "inputAlignTo" and link[2] is stereo for link in p.links)
    (manip,) = p.of(dai.node.ImageManip)
    assert {c.name: c.args for c in p.calls_of(manip)}["setFrameType"] == (dai.ImgFrame.Type.BGR888i,)
    (nn,) = p.of(dai.node.NeuralNetwork)
    (archive_call,) = p.calls_of(nn, "setNNArchive")
    assert isinstance(archive_call.args[0], dai.NNArchive)


def test_no_pose_model_builds_colour_and_depth_only() -> None:
    p = _build("RVC2", None)
    assert not p.of(dai.node.NeuralNetwork) and not p.of(dai.node.ImageManip)
    assert len(p.of(dai.node.Camera)) == 3


def test_hand_networks_on_rvc2_and_refused_on_rvc4() -> None:
    hands = resolve_hand_models("lite", "RVC2")
    assert hands.palm_input_size == (128, 128) and hands.landmark_input_size == (224, 224)
    p = _build("RVC2", None, hands)
    (manip,) = p.of(dai.node.ImageManip)
    palm, landmark = p.of(dai.node.NeuralNetwork)
    (sync,) = p.of(dai.node.Sync)
    assert {c.name: c.args for c in p.calls_of(manip)}["setOutputSize"][:2] == (128, 128)
    assert {c.name: c.args for c in p.calls_of(manip)}["setFrameType"] == (dai.ImgFrame.Type.BGR888p,)
    assert p.linked(manip, "out", palm, "input") and p.linked(palm, "out", sync, "inputs['palm']")
    assert [c.args for c in p.calls_of(landmark, "setBlobPath")] == [(hands.landmark,)]
    streams = p.streams  # type: ignore[attr-defined]
    assert streams.landmark_in.type == "depthai.InputQueue"
    assert streams.landmark_out.type == "depthai.MessageQueue"
    with pytest.raises(
        DeviceError,
        match=r"run on RVC2, but the connected OAK is RVC4; use hands=zoo or hands=PALM.tar.xz\+LANDMARKS.tar.xz "
        r"\(NN archives for RVC4\), or hands=none$",
    ):
        _build("RVC4", None, hands)


def test_platform_selection() -> None:
    for platform in ("RVC2", "RVC4"):
        check_platform(platform)
    with pytest.raises(DeviceError, match=r"platform must be one of RVC2, RVC4, got 'RVC3'"):
        check_platform("RVC3")
    with pytest.raises(DeviceError, match="got 'RVC3'"):
        build_device_pipeline(SpecPipeline(), "RVC3", SIZE, FPS, None)


def test_nn_input_type_comes_from_the_archive(rvc2_archive: Path, tmp_path: Path) -> None:
    rvc2 = resolve_pose_model(str(rvc2_archive), "RVC2")
    assert rvc2.frame_type == "BGR888p" and rvc2.platforms == ("RVC2",) and rvc2.input_size == (192, 192)
    p = _build("RVC2", rvc2)
    (manip,) = p.of(dai.node.ImageManip)
    assert {c.name: c.args for c in p.calls_of(manip)}["setFrameType"] == (dai.ImgFrame.Type.BGR888p,)
    (nn,) = p.of(dai.node.NeuralNetwork)
    assert len(p.calls_of(nn, "setNNArchive")) == 1 and not p.calls_of(nn, "setBlobPath")
    assert resolve_pose_model("lightning", "RVC2").frame_type == "RGB888p"
    untyped = make_archive(tmp_path / "untyped.tar.xz", "model.dlc", b"\0" * 64, None, [1, 192, 192, 3], "NHWC")
    assert resolve_pose_model(str(untyped), "RVC4").frame_type == "BGR888i"
    odd = make_archive(tmp_path / "odd.tar.xz", "model.dlc", b"\0" * 64, "RAW16", [1, 192, 192, 3], "NHWC")
    with pytest.raises(InputError, match="declares input type 'RAW16'; expected one of BGR888p"):
        resolve_pose_model(str(odd), "RVC4")


def test_archive_without_input_width_is_a_one_line_input_error(tmp_path: Path) -> None:
    archive = make_archive(tmp_path / "flat.tar.xz", "model.dlc", b"\0" * 64, "BGR888i", [1, 3], "NC")
    assert dai.NNArchive(str(archive)).getInputWidth() is None  # depthai's own answer
    with pytest.raises(InputError) as info:
        resolve_pose_model(str(archive), "RVC4")
    message = str(info.value)
    assert "does not declare an image input width and height (input shape [1, 3])" in message
    assert "\n" not in message


def test_fps_and_size_are_checked_against_the_sensors() -> None:
    lite = camera_features(35.0, 99.0)  # OAK-D Lite: IMX214 colour tops out near 35 fps at full size
    check_stream_limits(lite, SIZE, 30.0)
    with pytest.raises(
        DeviceError, match="oak fps 60 is above the 35 fps maximum of the IMX214 sensor on CAM_A for a 640x400 output"
    ):
        check_stream_limits(lite, SIZE, 60.0)
    # a faster binned mode counts only for outputs it is large enough for
    binned = camera_features(35.0, 99.0, binned_fps=60.0)  # 2104x1560 at 60 fps
    check_stream_limits(binned, SIZE, 60.0)
    with pytest.raises(DeviceError, match="above the 35 fps maximum .* for a 2560x1600 output"):
        check_stream_limits(binned, (2560, 1600), 60.0)
    with pytest.raises(
        DeviceError, match="oak fps 100 is above the 99 fps maximum of the OV7251 sensor on CAM_B for a 640x400 output"
    ):
        check_stream_limits(camera_features(120.0, 99.0), SIZE, 100.0)
    with pytest.raises(
        DeviceError, match="oak size 1920x1200 is larger than the IMX214 sensor on CAM_A \\(1280x800\\)"
    ):
        check_stream_limits(camera_features(60.0, 120.0, (1280, 800)), (1920, 1200), 30.0)
    with pytest.raises(DeviceError, match="no camera on CAM_C .* found CAM_A \\(IMX214\\), CAM_B \\(OV7251\\)"):
        check_stream_limits(lite[:2], SIZE, 30.0)


def test_usb_bandwidth_warning() -> None:
    rate = stream_bytes_per_s((640, 400), 30.0, (192, 192))
    assert rate == 30.0 * (640 * 400 * 5 + 1024)  # 38.4 MB/s + NN
    assert usb_warning("SUPER", rate) is None and usb_warning("UNKNOWN", rate) is None
    warning = usb_warning("HIGH", rate)
    assert warning is not None and "needs 38.4 MB/s, more than the ~35 MB/s USB2 carries" in warning
    assert usb_warning("HIGH", stream_bytes_per_s((640, 400), 15.0, None)) is None  # 19.2 MB/s fits
    assert "far too slow" in usb_warning("FULL", rate)


def test_signature_checker_rejects_wrong_calls() -> None:
    """The stand-in must fail on what the real depthai would reject."""
    with pytest.raises(AssertionError, match="accepts none of the arguments"):
        check_call(dai.node.StereoDepth, "setLeftRightCheck", ("yes",), {})
    with pytest.raises(AssertionError, match="accepts none of the arguments"):
        check_call(dai.node.Camera, "requestOutput", ((640, 400),), {"fpss": 30.0})
    with pytest.raises(AssertionError, match="has no 'setDepthAlignTo'"):
        check_call(dai.node.StereoDepth, "setDepthAlignTo", (), {})
    assert matches((640, 400), "tuple[int, int]") and not matches((640.0, 400), "tuple[int, int]")
    p = SpecPipeline()
    stereo = p.create(dai.node.StereoDepth)
    with pytest.raises(AssertionError, match="has no attribute 'alignInput'"):
        stereo.alignInput  # noqa: B018


def _dai_calls(path: Path) -> list[tuple[str, int, tuple[str, ...], int]]:
    """Calls ``dai.A.B(...)`` in a source file: (dotted name, positional count, keyword names, line)."""
    import ast

    calls = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Call):
            continue
        parts, target = [], node.func
        while isinstance(target, ast.Attribute):
            parts.append(target.attr)
            target = target.value
        if isinstance(target, ast.Name) and target.id == "dai" and parts:
            calls.append((".".join(reversed(parts)), len(node.args), tuple(k.arg for k in node.keywords), node.lineno))
    return calls


def test_every_module_level_depthai_call_in_the_driver_exists_with_its_arguments() -> None:
    """Static check of the ``dai.X(...)`` calls (constructors, free functions, static methods).

    Methods called on objects (device, pipeline, nodes, frames) are checked at run time by the
    other tests: device-side ones through dai_spec, host-side ones on real depthai objects.
    """
    from .dai_spec import _resolve, overloads

    root = Path(__file__).resolve().parents[2] / "drivers"
    checked = []
    for name in ("oak.py", "oak_pipeline.py", "oak_hands.py"):
        for dotted, n_pos, keywords, line in _dai_calls(root / name):
            obj = _resolve("depthai." + dotted)
            func = obj.__init__ if isinstance(obj, type) else obj
            sigs = overloads(func)
            assert sigs, f"{name}:{line}: dai.{dotted} has no parsable signature"
            fits = []
            for sig in sigs:
                params = [p for p in sig.params if p.name != "self"]
                names = [p.name for p in params]
                required = [p.name for p in params if not p.has_default]
                bound = names[:n_pos] + list(keywords)
                if n_pos <= len(params) and all(k in names[n_pos:] for k in keywords) and set(required) <= set(bound):
                    fits.append(sig)
            assert fits, (
                f"{name}:{line}: dai.{dotted} with {n_pos} positional and {keywords} keyword arguments fits no overload"
            )
            checked.append(dotted)
    # the calls this test must have seen (a refactor that hides them from the scan fails here)
    for expected in (
        "Pipeline",
        "Device",
        "NNArchive",
        "OpenVINO.Blob",
        "NNModelDescription",
        "getModelFromZoo",
        "ImgFrame",
    ):
        assert expected in checked, expected
