"""Live view of tracking: a Foxglove WebSocket server and a Rerun logger, fed without slowing the tracker.

``fusion-pf track SOURCE --serve [HOST:]PORT`` starts foxglove-sdk's own
WebSocket server (subprotocol ``foxglove.sdk.v1``, the protocol the Foxglove
app speaks) and streams, per frame, the messages the output MCAP gets: the
frame topics of :func:`drivers.mcap_record.frame_messages` (colour as JPEG
``foxglove.CompressedImage``, depth ``foxglove.RawImage``,
``foxglove.CameraCalibration``, skeleton, ground truth, hands) and the
``/tracker/*`` topics of :class:`drivers.tracker_topics.TrackerTopics`, which
writes them into the file and, through :meth:`Live.tee`, hands the very same
message objects to the live view. ``--rerun [URL]`` logs image, depth, cue
points, estimate (with its ``2 sigma_px`` disc, ``camera/uncertainty``; every target's with several), particles
and the 3-D palm to a Rerun viewer.

A multi-camera recording tracked in world coordinates (:meth:`Live.publish_world`)
streams every camera's frame topics under ``/<camera>``, the camera poses on
``/tf`` (with every instant: a client may join late), ``/tracker/world`` and
``/tracker/events`` to Foxglove; Rerun gets the rig in 3-D: under ``world`` (metres)
each camera's pose and pinhole with its colour and depth images and the targets'
estimates projected into it, the targets' world positions, and the events as a text log.

Slow clients
    The tracker thread only appends a frame to a bounded queue
    (:attr:`LiveOptions.live_queue` frames); a publisher thread encodes and
    sends. When the queue is full the oldest frame is dropped and counted.
    foxglove-sdk itself never blocks on a client: each client has an outbox of
    ``message_backlog_size`` messages and the oldest data message is dropped
    when it is full (the SDK reports "outbox for client ... full", counted here
    per client; the SDK does not expose a per-message count).
"""

from __future__ import annotations

import collections
import ipaddress
import logging
import re
import sys
import threading
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import IO, Any, Protocol, TypeVar

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame
from fusion_pf.options import option, validate
from fusion_pf.pipeline import TrackResult
from fusion_pf.pipeline.world import WorldResult
from fusion_pf.rig import CameraPose, FrameSet

__all__ = ["DEFAULT_RERUN_URL", "Live", "LiveOptions", "LiveStatus", "paced", "parse_address"]

#: Where ``--rerun`` without a URL connects: a Rerun viewer started with ``rerun`` on this machine.
DEFAULT_RERUN_URL = "rerun+http://127.0.0.1:9876/proxy"
#: Host ``--serve PORT`` listens on.
DEFAULT_HOST = "127.0.0.1"
#: Messages foxglove-sdk buffers per client before it drops the oldest (about 12 frames of every topic: 0.4 s at 30 fps).
CLIENT_BACKLOG = 96
#: Seconds the end of a run waits for the Foxglove server to stop (its clients to close).
STOP_WAIT_S = 1.0
#: JPEG quality of the streamed colour image.
JPEG_QUALITY = 80
#: Opacity (0-255) of the Rerun view's ``2 sigma_px`` disc around each estimate: the hand shows through it.
UNCERTAINTY_ALPHA = 60
#: Seconds between two status lines when stderr is not a terminal.
STATUS_EVERY_S = 5.0


def parse_address(text: str) -> tuple[str, int]:
    """``"[HOST:]PORT"`` -> ``(host, port)``; the host defaults to 127.0.0.1 (``[::1]:PORT`` for IPv6)."""
    host, sep, port = str(text).rpartition(":")
    host = host.strip("[]") if sep else DEFAULT_HOST
    try:
        number = int(port)
    except ValueError:
        raise InputError(f"expected [HOST:]PORT, e.g. 8765 or 127.0.0.1:8765, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise InputError(f"port must be in [0, 65535] (0: any free port), got {number} in {text!r}")
    if not host:
        raise InputError(f"expected [HOST:]PORT with a host before ':', got {text!r}")
    return host, number


def is_loopback(host: str) -> bool:
    """Whether ``host`` is this machine only (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _check_serve(label: str, value: Any) -> str:
    parse_address(value)
    return str(value)


def _check_rerun(label: str, value: Any) -> str:
    if not str(value).startswith(("rerun://", "rerun+http://", "rerun+https://")):
        raise InputError(f"{label} must be a Rerun URL like {DEFAULT_RERUN_URL}, got {value!r}")
    return str(value)


@dataclass(frozen=True)
class LiveOptions:
    """The live-view options of ``fusion-pf track`` (validated on construction)."""

    serve: str | None = option(
        None,
        kind="str",
        optional=True,
        check=_check_serve,
        metavar="[HOST:]PORT",
        show=lambda v: "off",
        help="stream the tracking live to Foxglove over a WebSocket (foxglove-sdk server; host 127.0.0.1 "
        "unless given; open ws://HOST:PORT in Foxglove)",
    )
    allow_remote: bool = option(
        False,
        kind="bool",
        help="let --serve listen on a host other than this machine (everyone who reaches it sees the camera)",
    )
    rerun: str | None = option(
        None,
        kind="str",
        optional=True,
        const=DEFAULT_RERUN_URL,
        check=_check_rerun,
        metavar="URL",
        show=lambda v: "off",
        help=f"log the tracking live to a running Rerun viewer (bare flag: {DEFAULT_RERUN_URL}, the viewer "
        "'rerun' starts)",
    )
    realtime: bool = option(
        False, kind="bool", help="pace a recording at its own timestamps (a live camera is paced by itself)"
    )
    live_queue: int = option(
        4,
        kind="int",
        lo=1,
        hi=1000,
        metavar="N",
        help="frames waiting for the live view; when full the oldest is dropped (counted), never the tracker slowed",
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.serve is not None:
            host, _ = parse_address(self.serve)
            if not is_loopback(host) and not self.allow_remote:
                raise InputError(
                    f"--serve {self.serve} listens on {host}, reachable from other machines; "
                    "pass --allow-remote to allow it, or serve on 127.0.0.1"
                )

    @property
    def enabled(self) -> bool:
        """Whether a live view (Foxglove or Rerun) is on."""
        return self.serve is not None or self.rerun is not None


class _Timed(Protocol):
    @property
    def timestamp_ns(self) -> int: ...


_T = TypeVar("_T", bound=_Timed)


def paced(frames: Iterable[_T]) -> Iterator[_T]:
    """Yield ``frames`` (or frame sets) no earlier than their own timestamps say, counted from the first (``--realtime``).

    A tracker slower than the recording is not waited for: a late frame is yielded at once.
    """
    start_wall = start_ts = None
    for frame in frames:
        if start_ts is None:
            start_wall, start_ts = time.perf_counter_ns(), frame.timestamp_ns
        else:
            assert start_wall is not None
            wait = (frame.timestamp_ns - start_ts) - (time.perf_counter_ns() - start_wall)
            if wait > 0:
                time.sleep(wait / 1e9)
        yield frame


def _px(result: TrackResult) -> str:
    """``(u, v) px`` of the estimate of ``result``, ``-`` without one."""
    e = result.estimate
    return "-" if e is None else f"({e.u:.0f}, {e.v:.0f}) px"


def _mm(xyz: np.ndarray | None) -> str:
    """``(x, y, z) mm`` of a world position, ``-`` without one."""
    return "-" if xyz is None else "({:.0f}, {:.0f}, {:.0f}) mm".format(*xyz)


class LiveStatus:
    """One live status line on the terminal: fps, state, palm in pixels and millimetres.

    On a terminal the line is rewritten in place (at most 10 times a second);
    otherwise a line is printed every :data:`STATUS_EVERY_S` seconds.
    """

    def __init__(self, stream: IO[str] | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._times: collections.deque[float] = collections.deque(maxlen=30)
        self._shown = 0.0
        self.extra = ""

    def line(self, result: TrackResult | WorldResult) -> str:
        """The status text of ``result``; with several targets each target's state and position in px (world: mm)."""
        fps = (len(self._times) - 1) / (self._times[-1] - self._times[0]) if len(self._times) > 1 else 0.0
        if isinstance(result, WorldResult):
            where = "  ".join(f"{t} {w.state} {_mm(w.position_mm)}" for t, w in result.targets.items())
            return f"instant {result.index}  {fps:5.1f} fps  {where}{self.extra}"
        if result.targets:
            where = "  ".join(f"{t} {r.state} {_px(r)}" for t, r in result.targets.items())
            return f"frame {result.frame}  {fps:5.1f} fps  {where}{self.extra}"
        mm = "" if result.xyz_mm is None else " ({:.0f}, {:.0f}, {:.0f}) mm".format(*result.xyz_mm)
        return f"frame {result.frame}  {fps:5.1f} fps  {result.state:<13} palm {_px(result)}{mm}{self.extra}"

    def update(self, result: TrackResult | WorldResult) -> None:
        """Count a frame (an instant) and show the line when it is time to."""
        now = time.perf_counter()
        self._times.append(now)
        if now - self._shown < (0.1 if self.tty else STATUS_EVERY_S):
            return
        self._shown = now
        if self.tty:
            self.stream.write("\r\x1b[K" + self.line(result))
        else:
            self.stream.write(self.line(result) + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End the status line (a newline after an in-place line)."""
        if self.tty and self._shown:
            self.stream.write("\n")
            self.stream.flush()


class _Tee:
    """A recorder that also keeps every tracker message for the live view (same objects, same code path)."""

    def __init__(self, recorder: Any, pending: list) -> None:
        self.recorder = recorder
        self.pending = pending

    def write_json(self, topic: str, schema_name: str, obj: Any, timestamp_ns: int, **kw: Any) -> None:
        self.recorder.write_json(topic, schema_name, obj, timestamp_ns, **kw)
        self.pending.append((topic, None, schema_name, obj))

    def write_protobuf(self, topic: str, message: Any, timestamp_ns: int) -> None:
        self.recorder.write_protobuf(topic, message, timestamp_ns)
        self.pending.append((topic, message, None, None))


@dataclass
class _Item:
    """One frame waiting for the live view."""

    frame: Frame
    messages: list
    result: TrackResult


@dataclass
class _WorldItem:
    """One instant of a multi-camera run waiting for the live view."""

    frameset: FrameSet
    messages: list
    result: WorldResult


#: foxglove-sdk's report of a subscription it refused: the client named a channel id it does not know (yet).
_REFUSED = re.compile(r"attempted to subscribe to unknown channel: (\d+)$")


class _SdkDrops(logging.Handler):
    """Counts foxglove-sdk's "outbox for client ADDR full" reports (oldest messages dropped) per client, and
    collects the channel ids of the subscriptions it refused (see :meth:`FoxgloveServer.publish`)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.full: collections.Counter[str] = collections.Counter()
        self.clients = 0
        self.refused: set[int] = set()
        self._lock = threading.Lock()

    def take_refused(self) -> set[int]:
        """The channel ids of the subscriptions refused since the last call."""
        with self._lock:
            ids, self.refused = self.refused, set()
        return ids

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        refused = _REFUSED.search(text)
        if refused is not None:
            with self._lock:
                self.refused.add(int(refused.group(1)))
        elif text.startswith("outbox for client ") and text.endswith(" full"):
            self.full[text[len("outbox for client ") : -len(" full")]] += 1
        elif text.startswith("Registered client"):
            self.clients += 1
        elif text.startswith("Unregistered client"):
            self.clients -= 1


class FoxgloveServer:
    """foxglove-sdk's WebSocket server with one channel per topic (created when first published).

    A channel created while a client is connected is advertised to it at once, and foxglove-sdk (0.30) only
    records the channel as advertised to that client after sending the advertisement: a client that answers
    with a subscription quicker than that (a loaded machine, one message in ten even unloaded) is refused
    ("Unknown channel ID") and would never get the topic. The SDK logs the refusal; :meth:`publish` then
    re-advertises that channel (closed, created anew under a new id), and the client subscribes again, as
    the Foxglove app and any client of the protocol do for a new channel of a topic they show. Channels that
    exist when a client connects are recorded before its subscriptions are read, so are never refused.
    """

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.server: Any = None
        self._channels: dict[str, Any] = {}
        self._schemas: dict[str, tuple[Any, str]] = {}
        self.drops = _SdkDrops()
        #: Channels created anew because a client's subscription to them was refused.
        self.readvertised = 0

    def open(self) -> str:
        import foxglove

        logger = logging.getLogger("foxglove")
        logger.addHandler(self.drops)
        logger.setLevel(logging.INFO)
        logger.propagate = False  # the SDK's own log lines stay off the terminal; the drops are summed up at the end
        if not logging.getLogger().handlers:
            logging.getLogger().addHandler(logging.NullHandler())  # keeps set_log_level from configuring the root
        foxglove.set_log_level("INFO")
        self._context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name="fusion-pf",
                host=self.host,
                port=self.port,
                context=self._context,
                message_backlog_size=CLIENT_BACKLOG,
            )
        except RuntimeError as exc:
            raise InputError(f"--serve {self.host}:{self.port}: cannot listen ({exc})") from None
        self.port = self.server.port
        from . import mcap_format as fmt

        # an event is rare: a channel advertised with its first message would lose that message to every client
        self._channel(fmt.EVENTS_TOPIC, None, fmt.EVENT_SCHEMA)
        return f"ws://{self.host}:{self.port}"

    def wants_frames(self) -> bool:
        """Whether a client subscribed to a frame topic (or none is advertised yet): frames are encoded only then."""
        from . import mcap_format as fmt

        frames = [c for t, c in self._channels.items() if t in fmt.FRAME_TOPICS]
        return not frames or any(c.has_sinks() for c in frames)

    def _channel(self, topic: str, message: Any, schema_name: str | None) -> Any:
        channel = self._channels.get(topic)
        if channel is None:
            from foxglove import Schema

            from . import mcap_format as fmt

            if message is not None:
                schema = Schema(
                    name=message.DESCRIPTOR.full_name,
                    encoding="protobuf",
                    data=fmt.protobuf_schema_data(type(message)),
                )
                self._schemas[topic] = (schema, "protobuf")
            else:
                assert schema_name is not None
                schema = Schema(name=schema_name, encoding="jsonschema", data=fmt.json_schema_data(schema_name))
                self._schemas[topic] = (schema, "json")
            channel = self._advertise(topic)
        return channel

    def _advertise(self, topic: str) -> Any:
        """A new channel of ``topic`` (its schema known), advertised to every client."""
        from foxglove import Channel

        schema, encoding = self._schemas[topic]
        channel = Channel(topic, schema=schema, message_encoding=encoding, context=self._context)
        self._channels[topic] = channel
        return channel

    def _readvertise_refused(self) -> None:
        """Advertise anew every channel a client's subscription to which the SDK refused (see the class doc)."""
        refused = self.drops.take_refused()
        for topic, channel in list(self._channels.items()):
            if channel.id() in refused:
                channel.close()
                self._advertise(topic)
                self.readvertised += 1

    def publish(self, messages: list, timestamp_ns: int) -> None:
        from . import mcap_format as fmt

        self._readvertise_refused()
        for topic, message, schema_name, obj in messages:
            channel = self._channel(topic, message, schema_name)
            data = message.SerializeToString() if message is not None else fmt.encode_json(obj, f"{topic} message")
            channel.log(data, log_time=timestamp_ns)

    def close(self) -> None:
        server, self.server = self.server, None
        for channel in self._channels.values():
            channel.close()
        if server is not None:
            # stop() waits for every client to close, ~50 s for one that does not read: not waited for
            stopper = threading.Thread(target=server.stop, name="fusion-pf-foxglove-stop", daemon=True)
            stopper.start()
            stopper.join(STOP_WAIT_S)
        logger = logging.getLogger("foxglove")
        logger.removeHandler(self.drops)


class RerunLogger:
    """Logs image, depth, cue points, estimate and its uncertainty, particles and the 3-D palm to a Rerun viewer at ``url``."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.rec: Any = None
        self._intrinsics = None
        self._cameras: dict[str, tuple[CameraPose, Any]] = {}

    def open(self) -> str:
        import socket
        from urllib.parse import urlsplit

        import rerun as rr

        where = urlsplit(self.url.replace("rerun+", "", 1))
        try:
            socket.create_connection((where.hostname or "127.0.0.1", where.port or 9876), timeout=2.0).close()
        except OSError as exc:
            raise InputError(
                f"--rerun {self.url}: no Rerun viewer answers ({exc.strerror or exc}); start one with 'rerun' "
                "(or 'rerun --serve-web --bind 127.0.0.1' for the web viewer)"
            ) from None
        self.rec = rr.RecordingStream("fusion-pf")
        self.rec.connect_grpc(self.url)
        return self.url

    def publish(self, item: _Item) -> None:
        import rerun as rr

        from . import mcap_format as fmt
        from .tracker_topics import OVERLAY_COLOURS

        rec, frame, result = self.rec, item.frame, item.result
        rec.set_time("capture", timestamp=np.datetime64(frame.timestamp_ns, "ns"))
        rec.set_time("frame", sequence=result.frame)
        k = frame.intrinsics
        if k != self._intrinsics:
            rec.log(
                "camera",
                rr.Pinhole(focal_length=[k.fx, k.fy], principal_point=[k.cx, k.cy], resolution=[k.width, k.height]),
                rr.Transform3D(),
            )
            self._intrinsics = k
        jpeg = fmt.encode_color(frame.color, frame.timestamp_ns, "jpeg", JPEG_QUALITY).data
        rec.log("camera/color", rr.EncodedImage(contents=jpeg, media_type="image/jpeg", draw_order=-10.0))
        if frame.depth is not None:  # behind the colour image in 2-D, a point cloud in 3-D
            rec.log("camera/depth", rr.DepthImage(frame.depth, meter=1000.0, draw_order=-20.0))
        if result.background:
            return

        def rgba(name: str) -> list[int]:
            return [round(255 * c) for c in OVERLAY_COLOURS.get(name, OVERLAY_COLOURS["other"])]

        # several targets: every target's particles, cues, estimate and palm, labelled by target
        results = result.targets or {"": result}
        particles = [r.particles for r in results.values() if r.particles is not None]
        if particles:
            rec.log("camera/particles", rr.Points2D(np.concatenate(particles), radii=1.0, colors=rgba("particles")))
        else:
            rec.log("camera/particles", rr.Clear(recursive=False))

        def label(target: str, text: str) -> str:
            return f"{target} {text}" if target else text

        cues = [(t, s, m) for t, r in results.items() for s, m in r.cues.items() if m is not None]
        rec.log(
            "camera/cues",
            rr.Points2D(
                [(m.u, m.v) for _, _, m in cues] or np.empty((0, 2)),
                radii=4.0,
                colors=[rgba(s) for _, s, _ in cues] or None,
                labels=[label(t, s) for t, s, _ in cues] or None,
            ),
        )

        def points(entity: str, uv: list[tuple[float, float]], **style: Any) -> None:
            """``uv`` as ``entity``'s 2-D points, or the entity cleared when there are none."""
            rec.log(entity, rr.Points2D(uv, **style) if uv else rr.Clear(recursive=False))

        found = [(t, r, r.estimate) for t, r in results.items() if r.estimate is not None]
        points(
            "camera/estimate",
            [(e.u, e.v) for _, _, e in found],
            radii=6.0,
            colors=rgba("estimate"),
            labels=[label(t, r.state) for t, r, _ in found],
        )
        # each estimate's uncertainty: a translucent disc of radius 2 sigma_px (image px), under the estimate
        sure = [(e, r.sigma_px) for _, r, e in found if r.sigma_px is not None]
        points(
            "camera/uncertainty",
            [(e.u, e.v) for e, _ in sure],
            radii=[2.0 * s for _, s in sure],
            colors=[*rgba("estimate")[:3], UNCERTAINTY_ALPHA],
            draw_order=-5.0,
        )
        palms = [(t, r.xyz_mm) for t, r in results.items() if r.xyz_mm is not None]
        if palms:
            rec.log(
                "camera/palm",
                rr.Points3D(
                    [np.asarray(xyz) / 1000.0 for _, xyz in palms],
                    radii=0.02,
                    colors=rgba("estimate"),
                    labels=[t for t, _ in palms] if result.targets else None,
                ),
            )

    def publish_world(self, item: _WorldItem) -> None:
        """One instant of a multi-camera run: under ``world`` (metres) every camera's pose, pinhole, images and the
        targets projected into it; the targets' world positions; the instant's events as a text log."""
        import rerun as rr

        from . import mcap_format as fmt
        from .tracker_topics import OVERLAY_COLOURS

        rec, result = self.rec, item.result
        rec.set_time("capture", timestamp=np.datetime64(item.frameset.timestamp_ns, "ns"))
        rec.set_time("frame", sequence=result.index)
        colour = [round(255 * c) for c in OVERLAY_COLOURS["estimate"]]
        for name, view in item.frameset.views.items():
            frame, pose, k = view.frame, view.pose, view.frame.intrinsics
            if self._cameras.get(name) != (pose, k):
                rec.log(
                    f"world/{name}",
                    rr.Transform3D(translation=pose.translation_mm / 1000.0, mat3x3=pose.rotation),
                    rr.Pinhole(focal_length=[k.fx, k.fy], principal_point=[k.cx, k.cy], resolution=[k.width, k.height]),
                )
                self._cameras[name] = (pose, k)
            jpeg = fmt.encode_color(frame.color, frame.timestamp_ns, "jpeg", JPEG_QUALITY).data
            rec.log(f"world/{name}/color", rr.EncodedImage(contents=jpeg, media_type="image/jpeg", draw_order=-10.0))
            if frame.depth is not None:
                rec.log(f"world/{name}/depth", rr.DepthImage(frame.depth, meter=1000.0, draw_order=-20.0))
            seen = [(t, w.pixels.get(name)) for t, w in result.targets.items()]
            seen = [(t, uv) for t, uv in seen if uv is not None]
            if seen:
                rec.log(
                    f"world/{name}/estimate",
                    rr.Points2D([uv for _, uv in seen], radii=6.0, colors=colour, labels=[t for t, _ in seen]),
                )
            else:
                rec.log(f"world/{name}/estimate", rr.Clear(recursive=False))
        if result.background:
            return
        found = [(t, w) for t, w in result.targets.items() if w.position_mm is not None]
        if found:
            rec.log(
                "world/targets",
                rr.Points3D(
                    [w.position_mm / 1000.0 for _, w in found],
                    radii=0.03,
                    colors=colour,
                    labels=[f"{t} {w.state}" for t, w in found],
                ),
            )
        else:
            rec.log("world/targets", rr.Clear(recursive=False))
        for event in result.events:
            rec.log("events", rr.TextLog(f"{event.event}: {'+'.join(event.targets)}", level="INFO"))

    def close(self) -> None:
        rec, self.rec = self.rec, None
        if rec is not None:
            try:
                rec.flush(timeout_sec=2.0)
            finally:
                rec.disconnect()


class Live:
    """The live view of one ``track`` run: Foxglove server and/or Rerun logger, a publisher thread, a status line.

    Use as a context manager. Per frame, the tracker calls :meth:`publish`
    after writing the frame's topics through :meth:`tee`; it never waits for a
    client.

    Attributes
    ----------
    published, dropped : int
        Frames handed to the viewers, and frames dropped because the queue
        was full (the publisher fell behind).
    """

    def __init__(self, options: LiveOptions, *, stream: IO[str] | None = None) -> None:
        self.options = options
        self.stream = stream if stream is not None else sys.stderr
        self.foxglove = None if options.serve is None else FoxgloveServer(*parse_address(options.serve))
        self.rerun = None if options.rerun is None else RerunLogger(options.rerun)
        self.status = LiveStatus(self.stream)
        self._queue: collections.deque[_Item | _WorldItem] = collections.deque()
        self._cv = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._pending: list = []
        self.published = self.dropped = 0
        self.error: BaseException | None = None

    def __enter__(self) -> Live:
        opened: list[Any] = []
        try:
            for sink, what in ((self.foxglove, "Foxglove"), (self.rerun, "Rerun")):
                if sink is not None:
                    where = sink.open()
                    opened.append(sink)
                    self.stream.write(f"fusion-pf: live view for {what} at {where}\n")
        except BaseException:
            for sink in opened:
                sink.close()
            raise
        self.stream.flush()
        self._thread = threading.Thread(target=self._run, name="fusion-pf-live", daemon=True)
        self._thread.start()
        return self

    def tee(self, recorder: Any) -> _Tee:
        """A stand-in for ``recorder`` that writes to it and keeps the messages for :meth:`publish`."""
        return _Tee(recorder, self._pending)

    def publish(self, result: TrackResult, frame: Frame) -> None:
        """Queue ``frame`` and the tracker messages written since the last call; drop the oldest when full."""
        self._enqueue(_Item(frame, list(self._pending), result))
        if not result.background:
            self.status.update(result)

    def publish_world(self, result: WorldResult) -> None:
        """Queue one instant of a multi-camera run (``result.frameset``) and the tracker messages written since."""
        if result.frameset is None:
            raise InputError(f"the live view of instant {result.index} needs its frame set")
        self._enqueue(_WorldItem(result.frameset, list(self._pending), result))
        if not result.background:
            self.status.update(result)

    def _enqueue(self, item: _Item | _WorldItem) -> None:
        self._pending.clear()
        with self._cv:
            if len(self._queue) >= self.options.live_queue:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(item)
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._queue and not self._stop:
                    self._cv.wait()
                if not self._queue:
                    return
                item = self._queue.popleft()
            try:
                self._send(item)
            except Exception as exc:  # a viewer failing must not end the run: reported at the end
                self.error = self.error or exc
            self.published += 1

    def _send(self, item: _Item | _WorldItem) -> None:
        from .mcap_record import frame_messages

        if isinstance(item, _WorldItem):
            self._send_world(item)
            return
        t = item.frame.timestamp_ns
        if self.foxglove is not None:
            frame = frame_messages(item.frame, "jpeg", JPEG_QUALITY, "raw") if self.foxglove.wants_frames() else []
            self.foxglove.publish(frame + item.messages, t)
        if self.rerun is not None:
            self.rerun.publish(item)

    def _send_world(self, item: _WorldItem) -> None:
        from . import mcap_format as fmt
        from .mcap_record import camera_messages, frame_messages

        t = item.frameset.timestamp_ns
        if self.foxglove is not None:
            views = item.frameset.views
            poses: Mapping[str, CameraPose] = {name: view.pose for name, view in views.items()}
            tf = [(fmt.TF_TOPIC, fmt.encode_transform(name, pose, t), None, None) for name, pose in poses.items()]
            frames = [
                m
                for name, view in views.items()
                for m in camera_messages(frame_messages(view.frame, "jpeg", JPEG_QUALITY, "raw"), name)
            ]
            self.foxglove.publish(tf + frames + item.messages, t)
        if self.rerun is not None:
            self.rerun.publish_world(item)

    def summary(self) -> str:
        """One line: frames published and dropped, and the clients whose outbox overflowed."""
        parts = [f"live view: {self.published} frames published, {self.dropped} dropped (publisher behind)"]
        if self.foxglove is not None:
            full = self.foxglove.drops.full
            parts += [
                f"Foxglove client {addr}: outbox full {n} time{'s' if n != 1 else ''}, oldest messages dropped"
                for addr, n in sorted(full.items())
            ]
        if self.error is not None:
            parts.append(f"a viewer failed: {type(self.error).__name__}: {self.error}")
        return "; ".join(parts)

    def __exit__(self, *exc: object) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify()
        if self._thread is not None:
            self._thread.join()
        self.status.close()
        for sink in (self.foxglove, self.rerun):
            if sink is not None:
                try:
                    sink.close()
                except Exception as exc:  # a viewer that went away: said in the summary, the outputs stand
                    self.error = self.error or exc
        self.stream.write(f"fusion-pf: {self.summary()}\n")
        self.stream.flush()
