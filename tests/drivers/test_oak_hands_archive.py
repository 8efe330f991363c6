"""Hand networks from NN archives (``hands=zoo`` / ``hands=PALM.tar.xz+LANDMARKS.tar.xz``), the RVC4 path.

No RVC4 device or zoo archive is reachable here. The archives are written as
Luxonis' tools write them (``config.json`` + a DLC model file, from which
depthai itself reads the platform) and read back by the real ``dai.NNArchive``;
the device pipeline is built on :class:`dai_spec.SpecPipeline` (every call
checked against the installed depthai); the palm tensors are built so the
expected hand rectangle follows from MediaPipe's rules worked by hand; the
landmark network's place is taken by a real host node behind real depthai
queues (:class:`test_oak_hands._LandmarkEcho`). The zoo look-up runs the real
``dai.getModelFromZoo``, which fails here for lack of network.
"""

from __future__ import annotations

import io
import json
import tarfile
from pathlib import Path

import depthai as dai
import numpy as np
import pytest

from drivers.base import SourceStats
from drivers.oak import ClockMap, GroupConverter, OakConfig, OakSource
from drivers.oak_hands import (
    HAND_ZOO_MODELS,
    HandTracker,
    decode_archive_palms,
    decode_landmarks,
    resolve_hand_models,
)
from drivers.oak_pipeline import build_device_pipeline, builtin_model_path
from fusion_pf.cues.hand import ssd_anchors
from fusion_pf.errors import DeviceError, InputError
from fusion_pf.frame import Intrinsics

from .dai_spec import _REAL, SpecPipeline, overloads
from .test_oak_hands import _colour_with_dot, _LandmarkEcho
from .test_oak_open import _answers, connect  # noqa: F401  (pytest fixture)

W, H = 640, 400
L = 640  # letterbox square side
PAD_Y = (L - H) / 2
PALM_SIDE = 192
LM_SIDE = 224
PALM_OUTPUTS = [("Identity", [1, 2016, 18]), ("Identity_1", [1, 2016, 1])]
LM_OUTPUTS = ["Identity", "Identity_1", "Identity_2"]


def _archive(
    path: Path,
    side: int,
    outputs: list[tuple[str, list[int]]],
    heads: list[list[str]],
    *,
    model_file: str = "model.dlc",
    data: bytes = b"\0" * 64,
    dai_type: str = "BGR888i",
    shape: list[int] | None = None,
) -> Path:
    """An NN archive (config.json + model file) as Luxonis' tools write it."""
    config = {
        "config_version": "1.0",
        "model": {
            "metadata": {"name": path.stem, "path": model_file, "precision": "int8"},
            "inputs": [
                {
                    "name": "image",
                    "dtype": "uint8",
                    "input_type": "image",
                    "shape": shape or [1, side, side, 3],
                    "layout": "NHWC",
                    "preprocessing": {
                        "mean": [0, 0, 0],
                        "scale": [255, 255, 255],
                        "reverse_channels": False,
                        "interleaved_to_planar": False,
                        "dai_type": dai_type,
                    },
                }
            ],
            "outputs": [{"name": n, "dtype": "float32", "shape": s} for n, s in outputs],
            "heads": [{"parser": f"Parser{i}", "outputs": o, "metadata": {}} for i, o in enumerate(heads)],
        },
    }
    with tarfile.open(path, "w:xz") as tar:
        for name, payload in (("config.json", json.dumps(config).encode()), (model_file, data)):
            info = tarfile.TarInfo(name)
            info.size = len(payload)
            tar.addfile(info, io.BytesIO(payload))
    return path


def _palm_archive(path: Path, **kwargs) -> Path:
    return _archive(path, PALM_SIDE, PALM_OUTPUTS, [[n for n, _ in PALM_OUTPUTS]], **kwargs)


def _landmark_archive(path: Path, **kwargs) -> Path:
    outputs = [("Identity", [1, 63]), ("Identity_1", [1, 1]), ("Identity_2", [1, 1]), ("Identity_3", [1, 63])]
    return _archive(path, LM_SIDE, outputs, [["Identity"], ["Identity_1"], ["Identity_2"]], **kwargs)


@pytest.fixture()
def rvc4_spec(tmp_path: Path) -> str:
    palm = _palm_archive(tmp_path / "palm.tar.xz")
    landmark = _landmark_archive(tmp_path / "landmark.tar.xz")
    return f"{palm}+{landmark}"


def _palm_nn(centre_px, size_px: float, angle: float, names=("Identity", "Identity_1"), logit=5.0) -> dai.NNData:
    """Palm output (192x192 input, 2016 anchors) with one detection, repeated on a neighbouring anchor.

    Square box of ``size_px`` colour pixels at ``centre_px``; wrist -> middle-finger base
    ``angle`` radians clockwise from "up". The duplicate must be merged by weighted NMS.
    """
    anchors = ssd_anchors(PALM_SIDE)
    cx = (centre_px[0] + 0.5) / L  # pixel centre -> continuous -> normalised letterbox square
    cy = (centre_px[1] + 0.5 + PAD_Y) / L
    order = np.argsort((anchors[:, 0] - cx) ** 2 + (anchors[:, 1] - cy) ** 2)
    scores = np.full(len(anchors), -10.0)
    boxes = np.zeros((len(anchors), 18))
    up = np.array([np.sin(angle), -np.cos(angle)])
    for k, score in ((order[0], logit), (order[1], logit - 1.0)):
        scores[k] = score
        centre = (np.array([cx, cy]) - anchors[k]) * PALM_SIDE
        boxes[k, 0:2] = centre
        boxes[k, 2:4] = size_px / L * PALM_SIDE
        boxes[k, 4:18] = np.tile(centre, 7)
        boxes[k, 4:6] = centre - 0.2 * boxes[k, 2] * up  # wrist
        boxes[k, 8:10] = centre + 0.3 * boxes[k, 2] * up  # middle-finger base
    nn = dai.NNData()
    nn.addTensor(names[0], boxes.astype(np.float32).reshape(1, -1, 18))
    nn.addTensor(names[1], scores.astype(np.float32).reshape(1, -1, 1))
    return nn


def _expected_corners(centre_px, size_px: float, angle: float) -> np.ndarray:
    """MediaPipe's hand rectangle worked by hand: 0.5 box towards the fingers, 2.6 x the box, rotated."""
    half = 2.6 * size_px / 2
    up = np.array([np.sin(angle), -np.cos(angle)])
    right = np.array([np.cos(angle), np.sin(angle)])
    c = np.array(centre_px) + 0.5 + 0.5 * size_px * up  # continuous coordinates
    return np.array([c + half * (-right + up), c + half * (right + up), c + half * (right - up)])


def test_archives_give_input_sizes_types_platform_and_outputs(rvc4_spec: str) -> None:
    models = resolve_hand_models(rvc4_spec, "RVC4")
    palm, landmark = (Path(p) for p in rvc4_spec.split("+"))
    assert (models.palm, models.landmark, models.kind) == (palm, landmark, "archive")
    assert models.palm_input_size == (192, 192) and models.landmark_input_size == (224, 224)
    assert models.palm_frame_type == models.landmark_frame_type == "BGR888i"
    assert models.platforms == ("RVC4",)
    assert models.palm_outputs == ("Identity", "Identity_1")
    assert models.landmark_outputs == tuple(LM_OUTPUTS)  # from the heads, not Identity_3 (world landmarks)
    assert OakConfig(hands=rvc4_spec).hands == rvc4_spec


def test_rvc4_pipeline_node_by_node(rvc4_spec: str) -> None:
    models = resolve_hand_models(rvc4_spec, "RVC4")
    p = SpecPipeline()
    streams = build_device_pipeline(p, "RVC4", (W, H), 30.0, None, models)
    (manip,) = p.of(dai.node.ImageManip)
    palm, landmark = p.of(dai.node.NeuralNetwork)
    (sync,) = p.of(dai.node.Sync)
    (align,) = p.of(dai.node.ImageAlign)
    assert p.linked(align, "outputAligned", sync, "inputs['depth']")
    calls = {c.name: c.args for c in p.calls_of(manip)}
    assert calls["setOutputSize"] == (192, 192, dai.ImageManipConfig.ResizeMode.LETTERBOX)
    assert calls["setFrameType"] == (dai.ImgFrame.Type.BGR888i,)  # the archive's dai_type
    assert calls["setMaxOutputFrameSize"] == (192 * 192 * 3,)
    (cam,) = [c for c in p.of(dai.node.Camera) if p.calls_of(c, "build")[0].args[0] == dai.CameraBoardSocket.CAM_A]
    assert p.linked(cam, "requestOutput#0", manip, "inputImage")
    assert p.linked(manip, "out", palm, "input") and p.linked(palm, "out", sync, "inputs['palm']")
    for node, side in ((palm, 192), (landmark, 224)):
        (archive_call,) = p.calls_of(node, "setNNArchive")
        archive = archive_call.args[0]
        assert isinstance(archive, dai.NNArchive)
        assert archive.getInputWidth() == side
        assert [pl.name for pl in archive.getSupportedPlatforms()] == ["RVC4"]
        assert not p.calls_of(node, "setBlobPath")
    assert not [c for c in p.calls_of(landmark) if c.name == "link"]  # fed by the host only
    assert streams.landmark_in.type == "depthai.InputQueue"
    assert streams.landmark_out.type == "depthai.MessageQueue"
    assert p.calls_of(landmark, "createInputQueue")[0].kwargs == {"maxSize": 2, "blocking": False}


def test_rvc4_archives_are_refused_on_rvc2_and_mixed_platforms_anywhere(rvc4_spec: str, tmp_path: Path) -> None:
    models = resolve_hand_models(rvc4_spec, "RVC4")
    with pytest.raises(DeviceError, match=r"run on RVC4, but the connected OAK is RVC2; use hands=zoo or"):
        build_device_pipeline(SpecPipeline(), "RVC2", (W, H), 30.0, None, models)
    blob = builtin_model_path("lightning").read_bytes()  # an RVC2 archive: depthai reads the platform from .blob
    palm2 = _palm_archive(tmp_path / "palm2.tar.xz", model_file="model.blob", data=blob, dai_type="BGR888p")
    mixed = resolve_hand_models(f"{palm2}+{rvc4_spec.split('+')[1]}", "RVC2")
    assert mixed.platforms == () and mixed.palm_frame_type == "BGR888p" and mixed.landmark_frame_type == "BGR888i"
    with pytest.raises(DeviceError, match="run on no common platform, but the connected OAK is RVC2"):
        build_device_pipeline(SpecPipeline(), "RVC2", (W, H), 30.0, None, mixed)


@pytest.mark.parametrize("angle", [0.0, np.pi / 6, -np.pi / 2])
def test_palm_rectangle_follows_mediapipe(angle: float) -> None:
    centre, size = (300.0, 180.0), 60.0
    (region,) = decode_archive_palms(_palm_nn(centre, size, angle), (W, H), (192, 192), ("Identity", "Identity_1"))
    assert region.score == pytest.approx(1 / (1 + np.exp(-5.0)))
    np.testing.assert_allclose(region.corners, _expected_corners(centre, size, angle), atol=1e-3)
    # output order does not matter: the larger tensor is the boxes
    swapped = _palm_nn(centre, size, angle, names=("b", "a"))
    (again,) = decode_archive_palms(swapped, (W, H), (192, 192), ("a", "b"))
    np.testing.assert_allclose(again.corners, region.corners)


def test_palm_decoding_errors_and_no_detection() -> None:
    outputs = ("Identity", "Identity_1")
    assert decode_archive_palms(_palm_nn((300, 180), 60, 0.0, logit=-3.0), (W, H), (192, 192), outputs) == []
    with pytest.raises(InputError, match=r"must hold \['Identity', 'Identity_1'\], got layers \[\]"):
        decode_archive_palms(dai.NNData(), (W, H), (192, 192), outputs)
    with pytest.raises(InputError, match="must have 896 scores and 896 x 18 boxes for a 128x128 input, got 2016"):
        decode_archive_palms(_palm_nn((300, 180), 60, 0.0), (W, H), (128, 128), outputs)
    nn = dai.NNData()
    nn.addTensor("Identity", np.zeros((1, 2016, 18), np.float32))
    nn.addTensor("Identity_1", np.full((1, 2016, 1), np.nan, np.float32))
    with pytest.raises(InputError, match="must be finite"):
        decode_archive_palms(nn, (W, H), (192, 192), outputs)


@pytest.mark.parametrize("angle", [0.0, np.pi / 5])
def test_landmark_round_trip_through_real_queues(rvc4_spec: str, angle: float) -> None:
    models = resolve_hand_models(rvc4_spec, "RVC4")
    dot = (310, 150)
    rgb, img = _colour_with_dot(dot)
    with dai.Pipeline(False) as pipeline:
        echo = pipeline.create(_LandmarkEcho)
        echo.names = models.landmark_outputs
        crops = echo.input.createInputQueue()
        tracker = HandTracker(models, crops, echo.out.createOutputQueue())
        pipeline.start()
        (hand,) = tracker.track(_palm_nn((300.0, 180.0), 60.0, angle), img, rgb)
        pipeline.stop()
    np.testing.assert_allclose(hand.landmarks[:, :2], np.tile(dot, (21, 1)), atol=0.35)
    np.testing.assert_allclose(hand.landmarks[:, 2], 8.0 * 2.6 * 60.0 / LM_SIDE, rtol=1e-5)
    assert hand.handedness == "right" and hand.score == pytest.approx(0.9, abs=1e-6)


def test_crops_are_sent_in_the_archive_frame_type(rvc4_spec: str) -> None:
    models = resolve_hand_models(rvc4_spec, "RVC4")
    rgb, img = _colour_with_dot((310, 150))
    sent = []

    class Recorder:
        def send(self, message: dai.ImgFrame) -> None:
            sent.append(message)

    with dai.Pipeline(False) as pipeline:
        echo = pipeline.create(_LandmarkEcho)
        echo.names = models.landmark_outputs
        crops = echo.input.createInputQueue()

        class Forward(Recorder):
            def send(self, message: dai.ImgFrame) -> None:
                super().send(message)
                crops.send(message)

        tracker = HandTracker(models, Forward(), echo.out.createOutputQueue())
        pipeline.start()
        tracker.track(_palm_nn((300.0, 180.0), 60.0, 0.0), img, rgb)
        pipeline.stop()
    (crop,) = sent
    assert crop.getType() == dai.ImgFrame.Type.BGR888i
    assert (crop.getWidth(), crop.getHeight()) == (224, 224)
    assert crop.getSequenceNum() == img.getSequenceNum() and crop.getTimestamp() == img.getTimestamp()


def test_group_converter_writes_archive_hands_and_skips_bad_messages(rvc4_spec: str) -> None:
    models = resolve_hand_models(rvc4_spec, "RVC4")
    rgb, img = _colour_with_dot((310, 150))
    stats = SourceStats()
    with dai.Pipeline(False) as pipeline:
        echo = pipeline.create(_LandmarkEcho)
        echo.names = models.landmark_outputs
        tracker = HandTracker(models, echo.input.createInputQueue(), echo.out.createOutputQueue())
        pipeline.start()
        converter = GroupConverter(
            Intrinsics(W, H, 500.0, 500.0, 319.5, 199.5), ClockMap(0), None, stats, hands=tracker
        )
        frames = []
        for k, palm in enumerate([_palm_nn((300.0, 180.0), 60.0, 0.0), dai.NNData()]):
            group = dai.MessageGroup()
            img.setSequenceNum(k)
            group["colour"] = img
            group["palm"] = palm
            frames.append(converter.convert(group))
        pipeline.stop()
    assert len(frames[0].hands) == 1 and frames[1].hands is None
    assert stats.notes == [
        "skipped 1 bad hand message(s) (those frames have no hand); first: palm detection output must hold "
        "['Identity', 'Identity_1'], got layers []"
    ]


def test_landmark_output_names_come_from_the_model() -> None:
    from drivers.oak_hands import PalmRegion

    region = PalmRegion(0.9, np.array([[0.0, 0.0], [224.0, 0.0], [224.0, 224.0]]))
    nn = dai.NNData()
    nn.addTensor("Identity", np.full((1, 63), 112.0, np.float32))
    nn.addTensor("Identity_1", np.array([[0.9]], np.float32))
    nn.addTensor("Identity_2", np.array([[0.2]], np.float32))
    hand = decode_landmarks(nn, region, 224, tuple(LM_OUTPUTS))
    np.testing.assert_allclose(hand.landmarks[:, :2], 111.5)  # crop centre, pixel-centre convention
    assert hand.handedness == "left"
    with pytest.raises(InputError, match=r"must hold \['Identity_dense/BiasAdd/Add', 'Identity_1', 'Identity_2'\]"):
        decode_landmarks(nn, region, 224)


def test_open_on_rvc4_records_hand_models_in_the_metadata(connect, rvc4_spec: str) -> None:  # noqa: F811
    make, pipelines = connect
    make(_answers(platform="RVC4"))
    with OakSource(OakConfig(pose="none", hands=rvc4_spec)) as source:
        meta = source.metadata()
        tracker = source._converter.hands
        assert tracker.models.kind == "archive" and tracker.landmark_in.type == "depthai.InputQueue"
        assert "inputs['palm']" in pipelines[0].feeds
    palm, landmark = rvc4_spec.split("+")
    assert meta["oak_hands"] == rvc4_spec and meta["oak_platform"] == "RVC4"
    assert meta["oak_hand_models"] == f"{palm} (BGR888i), {landmark} (BGR888i)"


def test_zoo_without_network_is_one_line_naming_the_offline_option(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("DEPTHAI_ZOO_CACHE_PATH", str(tmp_path / "empty-cache"))
    with pytest.raises(InputError) as info:
        resolve_hand_models("zoo", "RVC4")
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"hands=zoo could not get {HAND_ZOO_MODELS[0]} for RVC4 from the Luxonis model zoo (")
    assert "No internet connection" in message  # depthai's own reason, passed on
    assert "give hands=PALM.tar.xz+LANDMARKS.tar.xz" in message


def test_zoo_asks_for_both_slugs_for_the_connected_platform(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """What depthai is asked for (checked against its signature): the two slugs, the platform, cache first.

    A stand-in for ``getModelFromZoo`` answers with local archives: the zoo cannot be reached here.
    """
    asked = []
    palm = _palm_archive(tmp_path / "p.tar.xz")
    landmark = _landmark_archive(tmp_path / "l.tar.xz")
    (sig,) = overloads(_REAL["getModelFromZoo"])
    names = [q.name for q in sig.params]

    def zoo(*args, **kwargs):
        assert len(args) <= len(names) and set(kwargs) <= set(names[len(args) :]), (args, kwargs)
        bound = dict(zip(names, args, strict=False)) | kwargs
        description = bound["modelDescription"]
        assert isinstance(description, dai.NNModelDescription)
        asked.append((description.model, description.platform, bound["useCached"], bound["cacheDirectory"]))
        return str(palm if "palm" in description.model else landmark)

    monkeypatch.setattr(dai, "getModelFromZoo", zoo)
    monkeypatch.setenv("DEPTHAI_ZOO_CACHE_PATH", str(tmp_path))
    models = resolve_hand_models("zoo", "RVC4")
    assert asked == [(slug, "RVC4", True, str(tmp_path)) for slug in HAND_ZOO_MODELS]
    assert models.palm == palm and models.landmark == landmark and models.kind == "archive"


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("palm.tar.xz", r"hands must be none, lite, full, sparse \(RVC2 blobs\), zoo or PALM.tar.xz\+LANDMARKS"),
        ("a.blob+b.tar.xz", r"got 'a.blob\+b.tar.xz'"),
        ("a.tar.xz+b.tar.xz+c.tar.xz", "got 'a.tar.xz"),
        (".tar.xz+b.tar.xz", "got '.tar.xz"),
    ],
)
def test_bad_hands_specs(spec: str, message: str) -> None:
    with pytest.raises(InputError, match=message):
        OakConfig(hands=spec)
    with pytest.raises(InputError, match=message):
        resolve_hand_models(spec, "RVC4")


def test_missing_and_wrong_archives(tmp_path: Path) -> None:
    good_palm = _palm_archive(tmp_path / "palm.tar.xz")
    good_lm = _landmark_archive(tmp_path / "lm.tar.xz")
    with pytest.raises(InputError, match=r"hand model archive '.*nope.tar.xz' \(hands=.*\) does not exist$"):
        resolve_hand_models(f"{good_palm}+{tmp_path / 'nope.tar.xz'}", "RVC4")
    junk = tmp_path / "junk.tar.xz"
    junk.write_bytes(b"not an archive")
    with pytest.raises(InputError, match=r"^palm-detection model .*junk.tar.xz is not a readable NN archive: "):
        resolve_hand_models(f"{junk}+{good_lm}", "RVC4")
    three = _archive(tmp_path / "three.tar.xz", 192, [*PALM_OUTPUTS, ("x", [1, 1])], [["Identity"]])
    with pytest.raises(InputError, match=r"must have 2 outputs \(boxes n x 18, scores n\), got \['Identity', 'Id"):
        resolve_hand_models(f"{three}+{good_lm}", "RVC4")
    headless = _archive(tmp_path / "headless.tar.xz", 224, [("Identity", [1, 63])], [])
    with pytest.raises(InputError, match=r"must declare 3 heads \(landmarks, presence, handedness\) .* got heads \[\]"):
        resolve_hand_models(f"{good_palm}+{headless}", "RVC4")
    wide = _archive(tmp_path / "wide.tar.xz", 192, PALM_OUTPUTS, [["Identity"]], shape=[1, 192, 256, 3])
    with pytest.raises(InputError, match=r"must take a square input, got 256x192"):
        resolve_hand_models(f"{wide}+{good_lm}", "RVC4")
    flat = _archive(tmp_path / "flat.tar.xz", 192, PALM_OUTPUTS, [["Identity"]], shape=[1, 3])
    with pytest.raises(InputError, match=r"^palm-detection model .*flat.tar.xz does not declare an image input"):
        resolve_hand_models(f"{flat}+{good_lm}", "RVC4")
