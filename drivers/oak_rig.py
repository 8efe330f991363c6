"""Several live OAK cameras as one rig: one pipeline per device, frames matched on the host by timestamp.

``oak:device=ID1+ID2[+...]`` (device ids (MxId), names or IP addresses as
``dai.Device.getAllAvailableDevices()`` reports them, joined by ``+``) opens
one :class:`~drivers.oak.OakSource` per device, each with its own
``dai.Pipeline(device)`` built by :func:`drivers.oak_pipeline.build_device_pipeline`
(depthai's multi-device pipelines are RVC4-only), and yields
:class:`~fusion_pf.rig.FrameSet` objects that ``fusion-pf record`` writes with
:class:`drivers.rig.RigRecorder` (docs/recording-format.md, "Several cameras").
The other ``oak`` options (``size``, ``fps``, ``pose``, ``hands``, ``ir_laser``,
``timeout``) apply to every device.

Clock
    depthai keeps every device's clock synchronised to the host's steady clock
    (Luxonis: below 200 us (USB) / 500 us (PoE) at 1 sigma), so the cameras'
    ``getTimestamp()`` values are comparable; one :class:`~drivers.oak.ClockMap`
    taken when the rig starts maps them all to epoch nanoseconds.

Matching (:class:`RigSync`)
    Frames arrive per device in time order, the devices in any order. The
    earliest waiting frame (over all cameras) opens an instant; every other
    camera's next frame joins it when it is at most ``tolerance_ns`` (half a
    frame period) later, else that camera is absent from the instant. An
    instant is decided once every other camera has a later frame waiting or has
    ended, so the match does not depend on which device the host hears first.
    The instant takes the timestamp of its earliest frame (instants increase
    strictly). A frame without a partner is written alone, as its own instant,
    and counted per camera (``unmatched``); none is dropped. A frame older than
    an instant already emitted (a device clock going back) cannot be placed in
    time order: it is dropped, counted in ``stats.dropped`` and noted.

Camera names and poses
    With ``extrinsics=CAMS.yaml`` (``fusion-pf record --extrinsics``) the i-th
    device becomes the i-th camera of the file, with its pose, as in
    ``fusion-pf merge``. Without it the cameras are named ``oak_<device id>``
    and posed at the world origin (identity), with a warning: such a recording
    is the input of ``fusion-pf calibrate`` (a board seen by the cameras),
    which writes the extrinsics file for the next recording.
"""

from __future__ import annotations

import contextlib
import queue
import re
import threading
from collections import deque
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from fusion_pf.errors import DeviceError, FusionPFError, InputError
from fusion_pf.frame import Frame
from fusion_pf.rig import CameraPose, CameraView, FrameSet, check_camera_name

from .base import RigSource, SourceStats
from .oak import NO_DEVICE_MESSAGE, POLL_S, OakConfig, OakSource, _dai, select_device

__all__ = ["OakRig", "RigSync", "camera_name", "DEVICE_SEPARATOR", "IDENTITY_WARNING"]

#: Joins the device ids of ``oak:device=ID1+ID2``.
DEVICE_SEPARATOR = "+"
#: Prefix of a camera named after its device (no extrinsics file).
NAME_PREFIX = "oak_"
#: The warning of a rig recorded without extrinsics.
IDENTITY_WARNING = (
    "no --extrinsics: every camera is posed at the world origin (identity); record a ChArUco board and "
    "run fusion-pf calibrate for the real poses"
)
#: How far (ns) the newest frame may run ahead of an undecided instant before a silent camera is left out of it.
MAX_WAIT_NS = 1_000_000_000
#: Longest wait for a camera's reader thread after the rig closed.
JOIN_S = 2.0


def camera_name(device: str) -> str:
    """The rig camera name of a device id, name or address: ``oak_`` + it, other characters than ``[A-Za-z0-9_-]`` as ``_``."""
    return check_camera_name(NAME_PREFIX + re.sub(r"[^A-Za-z0-9_-]", "_", device)[:60], f"camera name of {device!r}")


@dataclass
class RigSync:
    """Matches several cameras' frame streams into instants (module docstring, "Matching").

    Parameters
    ----------
    cameras : sequence of str
        The cameras, in rig order.
    tolerance_ns : int
        Largest time from an instant's earliest frame to another camera's frame of it.
    max_wait_ns : int
        An instant waits for a silent camera (not ended, no frame waiting) only while the newest
        frame of any camera is less than this after it (default :data:`MAX_WAIT_NS`): a device
        that starts late or stalls holds at most that much of the others' frames in memory.

    Attributes
    ----------
    frames, unmatched : dict of str to int
        Per camera: frames in the instants emitted, and of those the ones without any other camera.
    late : dict of str to int
        Per camera: frames older than an instant already emitted (dropped).
    instants, complete : int
        Instants emitted, and those holding every camera.
    """

    cameras: Sequence[str]
    tolerance_ns: int
    max_wait_ns: int = 0
    frames: dict[str, int] = field(init=False)
    unmatched: dict[str, int] = field(init=False)
    late: dict[str, int] = field(init=False)
    instants: int = field(init=False, default=0)
    complete: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self.cameras = tuple(self.cameras)
        if len(set(self.cameras)) != len(self.cameras) or not self.cameras:
            raise InputError(f"rig cameras must be distinct and at least one, got {list(self.cameras)}")
        if isinstance(self.tolerance_ns, bool) or not isinstance(self.tolerance_ns, int) or self.tolerance_ns < 0:
            raise InputError(f"match tolerance must be an int >= 0 (ns), got {self.tolerance_ns!r}")
        self.frames = dict.fromkeys(self.cameras, 0)
        self.unmatched = dict.fromkeys(self.cameras, 0)
        self.late = dict.fromkeys(self.cameras, 0)
        self._waiting: dict[str, deque[Frame]] = {c: deque() for c in self.cameras}
        self._ended: set[str] = set()
        self._last: int | None = None
        self._newest = -1
        if not self.max_wait_ns:
            self.max_wait_ns = MAX_WAIT_NS

    def push(self, camera: str, frame: Frame) -> list[tuple[int, dict[str, Frame]]]:
        """Take ``camera``'s next frame; return the instants now decided, as ``(t, {camera: frame})`` (frames retimed to t)."""
        if camera not in self._waiting:
            raise InputError(f"camera {camera!r} is not in the rig ({', '.join(self.cameras)})")
        waiting = self._waiting[camera]
        newest = waiting[-1].timestamp_ns if waiting else self._last
        if newest is not None and frame.timestamp_ns <= newest:
            self.late[camera] += 1
            return []
        waiting.append(frame)
        self._newest = max(self._newest, frame.timestamp_ns)
        return self._ready()

    def end(self, camera: str) -> list[tuple[int, dict[str, Frame]]]:
        """``camera`` sends no more frames; return the instants now decided."""
        self._ended.add(camera)
        return self._ready()

    def flush(self) -> list[tuple[int, dict[str, Frame]]]:
        """Every camera has ended: every waiting frame, matched as far as it can be."""
        self._ended.update(self.cameras)
        return self._ready()

    def _ready(self) -> list[tuple[int, dict[str, Frame]]]:
        out = []
        while True:
            heads = [(w[0].timestamp_ns, k, c) for k, (c, w) in enumerate(self._waiting.items()) if w]
            if not heads:
                return out
            t, _k, first = min(heads)
            silent = [c for c, w in self._waiting.items() if c != first and not w and c not in self._ended]
            if silent and self._newest - t < self.max_wait_ns:
                return out  # a camera may still send a frame of this instant
            frames = {}
            for camera, waiting in self._waiting.items():
                if waiting and waiting[0].timestamp_ns - t <= self.tolerance_ns:
                    frames[camera] = _retimed(waiting.popleft(), t)
            for camera in frames:
                self.frames[camera] += 1
            if len(frames) == 1:
                self.unmatched[first] += 1
            self.instants += 1
            self.complete += len(frames) == len(self.cameras)
            self._last = t
            out.append((t, frames))

    def summary(self) -> str:
        """One line: instants, complete ones, and per camera the frames and those without a partner."""
        per = ", ".join(
            f"{c} {self.frames[c]} frames ({self.unmatched[c]} without a partner"
            + (f", {self.late[c]} out of time order dropped" if self.late[c] else "")
            + ")"
            for c in self.cameras
        )
        return f"{self.instants} instants, {self.complete} with every camera; {per}"


def _retimed(frame: Frame, t: int) -> Frame:
    import dataclasses

    return frame if frame.timestamp_ns == t else dataclasses.replace(frame, timestamp_ns=t)


_END = object()


class OakRig(RigSource):
    """Several live OAK cameras (module docstring). Iterate once inside ``with``; yields FrameSets.

    Parameters
    ----------
    configs : sequence of OakConfig
        One per device, each naming its ``device``.
    poses : mapping of str to CameraPose, or None
        Camera name -> pose, in device order (from an extrinsics file); None:
        ``oak_<device>`` names and identity poses (:data:`IDENTITY_WARNING`).
    """

    live = True

    def __init__(self, configs: Sequence[OakConfig], poses: Mapping[str, CameraPose] | None = None) -> None:
        super().__init__()
        devices = [c.device for c in configs]
        if len(devices) < 2 or any(d is None for d in devices):
            raise InputError(f"several OAK cameras need two or more device ids (device=ID1+ID2), got {devices}")
        if len(set(devices)) != len(devices):
            raise InputError(f"an OAK device is named twice in device={DEVICE_SEPARATOR.join(map(str, devices))}")
        self.configs = tuple(configs)
        self.devices = tuple(str(d) for d in devices)
        if poses is None:
            names = [camera_name(d) for d in self.devices]
            if len(set(names)) != len(names):
                raise InputError(f"the devices {', '.join(self.devices)} give the same camera name; use --extrinsics")
            self.poses = {name: CameraPose.identity() for name in names}
            self.posed = False
            self.rig_notes.append(IDENTITY_WARNING)
        else:
            if len(poses) != len(devices):
                raise InputError(
                    f"the extrinsics name {len(poses)} camera(s) ({', '.join(poses)}) but {len(devices)} OAK "
                    f"devices were given ({', '.join(self.devices)})"
                )
            self.poses = dict(poses)
            self.posed = True
        self.cameras = tuple(self.poses)
        fps = {c.fps for c in configs}
        self.tolerance_ns = int(round(0.5e9 / min(fps)))
        self.sync = RigSync(self.cameras, self.tolerance_ns)
        self.sources = {name: OakSource(config) for name, config in zip(self.cameras, configs, strict=True)}
        self._stack: contextlib.ExitStack | None = None
        self._iterated = False
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    @classmethod
    def from_options(cls, options: Mapping[str, object]) -> "OakRig":
        """The rig for ``oak:device=ID1+ID2,...`` options; ``extrinsics`` (a path) names and poses the cameras."""
        from .rig import load_extrinsics

        rest = {k: v for k, v in options.items() if k != "extrinsics"}
        devices = [d.strip() for d in str(rest.pop("device", "") or "").split(DEVICE_SEPARATOR)]
        if not all(devices):
            raise InputError(
                f"oak device must be ID or ID1{DEVICE_SEPARATOR}ID2{DEVICE_SEPARATOR}... (non-empty device ids), "
                f"got {options.get('device')!r}"
            )
        configs = [OakConfig.from_options({**rest, "device": d}) for d in devices]
        extrinsics = options.get("extrinsics")
        poses = None if extrinsics is None else load_extrinsics(Path(str(extrinsics)))
        return cls(configs, poses)

    def describe(self) -> str:
        """``"N OAK cameras WxH @ F fps, pose P"``."""
        w, h = self.configs[0].size
        return f"{len(self.cameras)} OAK cameras {w}x{h} @ {self.configs[0].fps:g} fps, pose {self.configs[0].pose}"

    def open(self) -> None:
        """Find every device first (one line naming a missing one), then open each; any failure closes them all.

        Raises
        ------
        DeviceError
            No OAK device at all (:data:`~drivers.oak.NO_DEVICE_MESSAGE`), a device id not found
            (naming it and the devices present), or a device failing to open (naming it).
        """
        dai = _dai()
        infos = dai.Device.getAllAvailableDevices()
        if not infos:
            raise DeviceError(NO_DEVICE_MESSAGE)
        for name, device in zip(self.cameras, self.devices, strict=True):
            try:
                select_device(infos, device)
            except DeviceError as exc:
                raise DeviceError(f"camera {name}: {exc}") from None
        clock = None
        with contextlib.ExitStack() as stack:
            for name, source in self.sources.items():
                source.clock = clock
                try:
                    stack.enter_context(source)
                except FusionPFError as exc:
                    raise type(exc)(f"camera {name} (device {source.config.device}): {exc}") from None
                clock = source.clock  # the first device's clock map serves every camera
            self._stack = stack.pop_all()

    def close(self) -> None:
        """Stop the reader threads and close every device (each bounded in time); safe to call twice."""
        self._stop.set()
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()
        for thread in self._threads:
            thread.join(JOIN_S)
        self._threads = []

    def _read(self, name: str, source: OakSource, out: queue.Queue) -> None:
        try:
            for frame in source:
                out.put((name, frame))
                if self._stop.is_set():
                    break
        except Exception as exc:  # the device's end, reported by the consumer
            out.put((name, exc))
        finally:
            out.put((name, _END))

    def _sets(self) -> Iterator[FrameSet]:
        if self._iterated:
            raise DeviceError("several OAK cameras are a live source and can be iterated once; record them")
        self._iterated = True
        if self._stack is None:
            raise RuntimeError("OakRig must be used inside a 'with' block")
        arrivals: queue.Queue = queue.Queue()
        for name, source in self.sources.items():
            thread = threading.Thread(
                target=self._read, args=(name, source, arrivals), name=f"oak-rig-{name}", daemon=True
            )
            thread.start()
            self._threads.append(thread)
        index = 0
        failure: tuple[str, BaseException] | None = None
        running = set(self.cameras)
        try:
            while running and failure is None:
                try:
                    name, item = arrivals.get(timeout=POLL_S)
                except queue.Empty:
                    continue
                if item is _END:
                    running.discard(name)
                    ready = self.sync.end(name)
                elif isinstance(item, BaseException):
                    failure = (name, item)
                    ready = []
                else:
                    ready = self.sync.push(name, item)
                for t, frames in ready:
                    yield self._set(index, t, frames)
                    index += 1
            while failure is not None:  # what the other devices delivered before: matched and written too
                try:
                    name, item = arrivals.get_nowait()
                except queue.Empty:
                    break
                if isinstance(item, Frame):
                    for t, frames in self.sync.push(name, item):
                        yield self._set(index, t, frames)
                        index += 1
            for t, frames in self.sync.flush():
                yield self._set(index, t, frames)
                index += 1
        finally:
            self._stop.set()
        if failure is not None:
            name, exc = failure
            text = " ".join(str(exc).split()) or type(exc).__name__
            raise DeviceError(f"camera {name} (device {self.sources[name].config.device}): {text}")

    def _set(self, index: int, t: int, frames: Mapping[str, Frame]) -> FrameSet:
        views = {name: CameraView(name, frame, self.poses[name]) for name, frame in frames.items()}
        return FrameSet(index, t, views)

    @property
    def stats(self) -> SourceStats:
        """Every camera's stats added up, their notes prefixed with the camera; the matching's notes."""
        total = SourceStats()
        for name, source in self.sources.items():
            s = source.stats
            total.frames += s.frames
            total.missing_depth += s.missing_depth
            total.missing_skeleton += s.missing_skeleton
            total.dropped += s.dropped + self.sync.late[name]
            total.notes += [f"camera {name}: {note}" for note in s.notes]
        total.notes += self.rig_notes
        if any(self.sync.late.values()) or any(self.sync.unmatched.values()):
            total.notes.append("matching: " + self.sync.summary())
        return total

    def matching(self) -> str:
        """:meth:`RigSync.summary`."""
        return self.sync.summary()

    def metadata(self) -> dict[str, str]:
        """``oak_devices``, ``oak_rig_poses``, ``oak_rig_tolerance_ns``, ``oak_rig_clock`` and each camera's
        :meth:`OakSource.metadata` as ``<camera>/<key>``."""
        out = {
            "oak_devices": ",".join(self.devices),
            "oak_rig_poses": "extrinsics file" if self.posed else "identity (no extrinsics; calibrate the rig)",
            "oak_rig_tolerance_ns": str(self.tolerance_ns),
            "oak_rig_clock": "one ClockMap for every device (depthai syncs each device clock to the host's)",
        }
        for name, source in self.sources.items():
            out.update((f"{name}/{key}", value) for key, value in source.metadata().items())
        return out
