"""Frame sources and sinks: MCAP replay and recorder, synthetic scenes, the OAK camera.

Use :func:`open_source` to get a source from a command-line spec.
"""

from __future__ import annotations

import os
from pathlib import Path

from fusion_pf.errors import InputError

from .base import FrameLoss, ReplaySource, RigSource, Sink, Source, SourceStats

__all__ = [
    "open_source",
    "open_rig",
    "is_rig_spec",
    "Source",
    "ReplaySource",
    "RigSource",
    "Sink",
    "SourceStats",
    "FrameLoss",
    "SOURCE_SPECS",
]

# depthai's crash handler (backward-cpp) allocates inside the signal handler: after a native crash inside malloc it
# deadlocks and the process never ends (a test worker hung 20 min in tests/drivers/test_oak_rig.py on 2026-11-28,
# glibc aborting in malloc under the handler). Without it a native crash ends the process, and Python's faulthandler
# (pytest enables it) says where. Set before any depthai import, which all go through this package.
os.environ.setdefault("DEPTHAI_INSTALL_SIGNAL_HANDLER", "0")

#: The source specs :func:`open_source` understands, for help texts.
SOURCE_SPECS = (
    "FILE.mcap (replay a recording), "
    "synth[:seed=S,frames=N,size=WxH,background_frames=K] (synthetic scene), "
    "oak[:size=WxH,fps=F] (live Luxonis OAK camera, needs the 'oak' extra; oak:device=ID1+ID2 for several), "
    "FOLDER of images, VIDEO file, Azure Kinect .mkv or ROS 1 .bag (read on the fly; "
    "see fusion-pf import for options and ROS 2 bags)"
)
#: Suffixes of files :func:`open_source` reads through :mod:`drivers.importers`.
IMPORT_SUFFIXES = (".mp4", ".m4v", ".avi", ".mov", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".mkv", ".bag")


def _parse_options(text: str, spec: str) -> dict[str, str]:
    options: dict[str, str] = {}
    for item in filter(None, text.split(",")):
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"source option {item!r} in {spec!r} must look like key=value")
        options[key.strip()] = value.strip()
    return options


def _is_rig(options: dict[str, object]) -> bool:
    return "extrinsics" in options or "+" in str(options.get("device") or "")


def is_rig_spec(spec: str | Path, **overrides: object) -> bool:
    """Whether ``spec`` (with ``overrides``) names several cameras: ``oak:device=ID1+ID2`` or an ``extrinsics`` option."""
    kind, _, rest = str(spec).partition(":")
    return kind == "oak" and _is_rig({**_parse_options(rest, str(spec)), **overrides})


def open_rig(spec: str | Path, **overrides: object) -> RigSource:
    """Return the (unopened) several-camera source named by ``spec`` (see :func:`is_rig_spec`); it yields frame sets.

    Raises
    ------
    InputError
        When ``spec`` names one camera or none.
    """
    if not is_rig_spec(spec, **overrides):
        raise InputError(f"{spec} does not name several cameras; expected oak:device=ID1+ID2[+...]")
    from .oak_rig import OakRig

    _, _, rest = str(spec).partition(":")
    return OakRig.from_options({**_parse_options(rest, str(spec)), **overrides})


def open_source(spec: str | Path, **overrides: object) -> Source:
    """Return the (unopened) source named by ``spec``.

    Parameters
    ----------
    spec : str or Path
        ``path/to/file.mcap``, ``synth:seed=3,frames=200``, ``oak[:...]``, or a folder
        of images, a video, an Azure Kinect ``.mkv`` or a ROS 1 ``.bag``
        (:func:`drivers.importers.open_import`).
    **overrides
        Keyword options given to the driver, overriding those in ``spec``.

    Returns
    -------
    Source
        Use it as a context manager.

    Raises
    ------
    InputError
        When the spec names no known source (the message lists the valid ones), or several
        cameras (:func:`open_rig` reads those).
    """
    text = str(spec)
    kind, _, rest = text.partition(":")
    if text.lower().endswith(".mcap"):
        from .mcap_replay import McapReplay

        return McapReplay(Path(text), **overrides)
    path = Path(text)
    if path.is_dir() or path.suffix.lower() in IMPORT_SUFFIXES:
        from .importers import open_import

        unknown = sorted(set(overrides) - {"fps"})
        if unknown:
            raise InputError(f"{', '.join(unknown)} cannot be set for {text}; it is read as it was recorded")
        return open_import(path, **overrides)
    if kind == "synth":
        from .synth import SynthSource

        return SynthSource.from_options({**_parse_options(rest, text), **overrides})
    if kind == "oak":
        options = {**_parse_options(rest, text), **overrides}
        if _is_rig(options):
            raise InputError(
                f"{text} names several cameras: record them with fusion-pf record {text} OUT.mcap; tracking "
                "several cameras at once is not built yet"
            )
        from .oak import OakSource

        return OakSource.from_options(options)
    raise InputError(f"unknown source {text!r}; expected one of: {SOURCE_SPECS}")
