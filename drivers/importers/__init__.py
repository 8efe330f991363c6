"""Importers: recordings made by other cameras and tools, as fusion-pf frame sources.

=====================================  =========================================  ==========================
source                                 what is read                               module
=====================================  =========================================  ==========================
ROS 2 bag (``.mcap`` file or bag dir)  sensor_msgs Image / CompressedImage /       :mod:`.ros`
ROS 1 ``.bag`` (RealSense, ...)        CameraInfo; colour/depth paired by time
Azure Kinect ``.mkv`` (k4arecorder)    COLOR + DEPTH tracks, calibration.json;    :mod:`.k4a`
                                       depth registered to colour
folder of images                       colour and/or depth images, by name         :mod:`.folder`
video file (mp4, avi, mov, ...)        colour only                                 :mod:`.video`
=====================================  =========================================  ==========================

:func:`open_import` picks the importer from the path; :func:`~.base.write_recording`
writes any of them into a fusion-pf MCAP recording (``fusion-pf import``).
"""

from __future__ import annotations

from pathlib import Path

from fusion_pf.errors import InputError

from .base import ImportSource, ImportSummary, IntrinsicsOption, write_recording
from .video import VIDEO_SUFFIXES

__all__ = [
    "open_import",
    "detect",
    "ImportSource",
    "ImportSummary",
    "IntrinsicsOption",
    "write_recording",
    "IMPORT_SPECS",
]

#: What :func:`open_import` accepts, for help texts.
IMPORT_SPECS = (
    "a ROS 2 bag (.mcap file or bag folder with metadata.yaml), a ROS 1 .bag, an Azure Kinect .mkv, "
    "a folder of colour and/or depth images, or a video file (" + ", ".join(VIDEO_SUFFIXES) + ")"
)


def _is_k4a(path: Path) -> bool:
    from .video import open_container

    with open_container(path) as container:
        return any(any(k.startswith("K4A_") for k in s.metadata) for s in container.streams)


def detect(path: str | Path) -> str:
    """The importer kind of ``path``: ``"ros"``, ``"k4a"``, ``"folder"`` or ``"video"``.

    Raises
    ------
    InputError
        When the path does not exist or is of no known kind.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path} does not exist")
    if path.is_dir():
        return "ros" if (path / "metadata.yaml").is_file() else "folder"
    suffix = path.suffix.lower()
    if suffix in (".mcap", ".bag", ".db3"):
        return "ros"
    if suffix == ".mkv":
        return "k4a" if _is_k4a(path) else "video"
    if suffix in VIDEO_SUFFIXES:
        return "video"
    raise InputError(f"cannot import {path}: unknown kind of file {suffix or '(no suffix)'}; expected {IMPORT_SPECS}")


def open_import(
    path: str | Path,
    *,
    color_topic: str | None = None,
    depth_topic: str | None = None,
    info_topic: str | None = None,
    depth_unit: str | None = None,
    fps: float | None = None,
    intrinsics: IntrinsicsOption | None = None,
) -> ImportSource:
    """The (unopened) importer for ``path``.

    Parameters
    ----------
    path : str or Path
        See :data:`IMPORT_SPECS`.
    color_topic, depth_topic, info_topic : str, optional
        ROS topics overriding the automatic choice (ROS bags only).
    depth_unit : str, optional
        Length of one depth count of an image folder (default ``"1mm"``).
    fps : float, optional
        Frame rate giving the timestamps of an image folder (default 30) or
        replacing a video's own timestamps.
    intrinsics : IntrinsicsOption, optional
        Colour intrinsics of a folder or video (file, flags or field of view),
        or of a ROS bag without camera info.

    Returns
    -------
    ImportSource
    """
    path = Path(path)
    kind = detect(path)
    topics = {"--color-topic": color_topic, "--depth-topic": depth_topic, "--info-topic": info_topic}
    given = [name for name, value in topics.items() if value is not None]
    if given and kind != "ros":
        raise InputError(f"{', '.join(given)} apply to ROS bags; {path} is a {kind}")
    if depth_unit is not None and kind != "folder":
        raise InputError(f"--depth-unit applies to image folders; {path} is a {kind} (its depth unit is known)")
    if intrinsics is not None and intrinsics.given and kind == "k4a":
        raise InputError(f"{path} is an Azure Kinect recording: its calibration is used, do not pass intrinsics")
    if kind == "ros":
        from .ros import RosBagSource

        if fps is not None:
            raise InputError(f"--fps does not apply to ROS bags; {path} has its own timestamps")
        return RosBagSource(
            path, color_topic=color_topic, depth_topic=depth_topic, info_topic=info_topic, intrinsics=intrinsics
        )
    if kind == "k4a":
        from .k4a import AzureKinectSource

        if fps is not None:
            raise InputError(f"--fps does not apply to Azure Kinect recordings; {path} has its own timestamps")
        return AzureKinectSource(path)
    if kind == "folder":
        from .folder import ImageFolderSource

        return ImageFolderSource(
            path, depth_unit=depth_unit or "1mm", fps=30.0 if fps is None else fps, intrinsics=intrinsics
        )
    from .video import VideoSource

    return VideoSource(path, fps=fps, intrinsics=intrinsics)
