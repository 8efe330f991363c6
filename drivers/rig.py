"""Multi-camera recordings: read them as :class:`~fusion_pf.rig.FrameSet` objects, write them, merge single-camera ones.

A multi-camera recording (docs/recording-format.md, "Several cameras") holds
each camera's convention topics under the prefix ``/<camera>``, the camera's
pose as a static ``foxglove.FrameTransform`` from ``world`` on ``/tf``, and the
frames of one instant with the same timestamp. Every camera is read by
:class:`~drivers.mcap_replay.McapReplay` (``camera=``), ``/tf`` and the world
ground truth by :class:`~drivers.mcap_replay.McapTopics`: one MCAP reading path.

Extrinsics files (YAML or JSON, written by ``fusion-pf calibrate`` or by hand)::

    cameras:
      - name: cam_left
        translation_mm: [-400.0, 0.0, 0.0]   # optical centre in the world
        rotation_xyzw: [0.0, 0.2588, 0.0, 0.9659]   # or rotation_matrix (3 rows) or rotation_rvec (radians)
      - name: cam_right
        ...
"""

from __future__ import annotations

import contextlib
import dataclasses
import heapq
import json
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame
from fusion_pf.rig import WORLD_FRAME, CameraPose, CameraView, FrameSet, check_camera_name

from . import mcap_format as fmt
from .mcap_record import McapRecorder
from .mcap_replay import McapReplay, McapTopics

_CAMERA_COLOR = re.compile(r"^/([^/]+)" + re.escape(fmt.COLOR_TOPIC) + "$")
#: Metadata key of ``fusion_pf.recording`` listing the cameras of a multi-camera recording, in order.
CAMERAS_KEY = "cameras"
#: Prefix of the ``fusion_pf.recording`` keys repeating each camera's pose (``pose_<camera>``, JSON).
POSE_KEY_PREFIX = "pose_"


def pose_metadata(pose: CameraPose) -> str:
    """The ``pose_<camera>`` metadata value of ``pose``: JSON ``{"translation_mm", "rotation_xyzw"}`` (exact floats)."""
    return json.dumps({"translation_mm": pose.translation_mm.tolist(), "rotation_xyzw": pose.quaternion().tolist()})


def _pose_from_metadata(text: str, where: str) -> CameraPose:
    try:
        obj = json.loads(text)
        return CameraPose.from_quaternion(obj["rotation_xyzw"], obj["translation_mm"])
    except (ValueError, KeyError, TypeError, InputError) as exc:
        raise RecordingError(f"{where}: not a pose ({exc}): {text[:80]!r}") from None


# --------------------------------------------------------------------------- extrinsics files


def _pose_from_entry(entry: Any, where: str) -> tuple[str, CameraPose]:
    if not isinstance(entry, dict):
        raise InputError(f"{where} must be a mapping with name, translation_mm and a rotation, got {entry!r}")
    name = check_camera_name(entry.get("name"), f"{where} name")
    where = f"{where} ({name})"
    if "translation_mm" not in entry:
        raise InputError(f"{where} has no translation_mm ([x, y, z] of the optical centre in the world, mm)")
    rotations = [key for key in ("rotation_xyzw", "rotation_matrix", "rotation_rvec") if key in entry]
    if len(rotations) != 1:
        raise InputError(
            f"{where} needs exactly one of rotation_xyzw, rotation_matrix, rotation_rvec, got {rotations or 'none'}"
        )
    key = rotations[0]
    try:
        t = np.asarray(entry["translation_mm"], dtype=np.float64)
        if key == "rotation_xyzw":
            return name, CameraPose.from_quaternion(entry[key], t)
        if key == "rotation_rvec":
            return name, CameraPose.from_rvec(entry[key], t)
        return name, CameraPose(np.asarray(entry[key], dtype=np.float64), t)
    except (InputError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: {exc}") from None


def load_extrinsics(path: str | Path) -> dict[str, CameraPose]:
    """Camera poses (in file order) from an extrinsics file (YAML or JSON, module docstring).

    ``cameras`` is a list of entries, or a mapping from name to entry (without ``name``).

    Raises
    ------
    InputError
        When the file is unreadable or an entry is malformed (naming the camera and field).
    """
    from .importers.base import load_document

    path = Path(path)
    if not path.is_file():
        raise InputError(f"extrinsics file not found: {path}")
    doc = load_document(path, "extrinsics file")
    where = f"extrinsics file {path}"
    cameras = doc.get("cameras") if isinstance(doc, dict) else None
    if isinstance(cameras, dict):
        cameras = [
            {"name": name, **(entry if isinstance(entry, dict) else {"": entry})} for name, entry in cameras.items()
        ]
    if not isinstance(cameras, list) or not cameras:
        raise InputError(f"{where} must hold a non-empty 'cameras' list (or mapping) of camera poses")
    poses: dict[str, CameraPose] = {}
    for k, entry in enumerate(cameras):
        name, pose = _pose_from_entry(entry, f"{where} camera {k}")
        if name in poses:
            raise InputError(f"{where}: camera {name!r} appears twice")
        poses[name] = pose
    return poses


def extrinsics_document(poses: Mapping[str, CameraPose], extra: Mapping[str, Mapping[str, Any]] | None = None) -> dict:
    """The extrinsics file's document for ``poses`` (``extra``: more keys per camera, e.g. the reprojection error)."""
    cameras = []
    for name, pose in poses.items():
        entry: dict[str, Any] = {
            "name": name,
            "translation_mm": [round(float(v), 4) for v in pose.translation_mm],
            "rotation_xyzw": [round(float(v), 9) for v in pose.quaternion()],
        }
        entry.update((extra or {}).get(name, {}))
        cameras.append(entry)
    return {"world": WORLD_FRAME, "cameras": cameras}


def write_extrinsics(path: str | Path, document: Mapping[str, Any]) -> None:
    """Write an extrinsics document as YAML (``.yaml``/``.yml``) or JSON (anything else)."""
    path = Path(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        from ruamel.yaml import YAML

        yaml = YAML(typ="safe")
        yaml.default_flow_style = None
        with open(path, "w") as fh:
            yaml.dump(json.loads(json.dumps(document)), fh)
    else:
        path.write_text(json.dumps(document, indent=2) + "\n")


# --------------------------------------------------------------------------- writing


class RigRecorder:
    """Write frame sets into one multi-camera MCAP (a context manager around :class:`McapRecorder`).

    The camera poses go on ``/tf`` with the first frame set (and into the
    recording metadata as ``pose_<camera>``, outside the chunks, so a damaged first
    chunk does not take them along); each camera's frame goes on its prefixed
    topics; world ground truth on ``/ground_truth/world``, the targets each camera sees on
    ``/ground_truth/visibility``.
    """

    def __init__(self, path: str | Path, poses: Mapping[str, CameraPose], **recorder_kwargs: Any) -> None:
        if not poses:
            raise InputError("a multi-camera recording needs at least one camera pose")
        self.poses = {check_camera_name(name): pose for name, pose in poses.items()}
        meta = dict(recorder_kwargs.pop("metadata", None) or {})
        meta[CAMERAS_KEY] = ",".join(self.poses)
        meta.update((POSE_KEY_PREFIX + name, pose_metadata(pose)) for name, pose in self.poses.items())
        self.recorder = McapRecorder(path, metadata=meta, **recorder_kwargs)
        self._posed = False
        self.sets_written = 0

    def __enter__(self) -> RigRecorder:
        self.recorder.open()
        self._posed = False
        return self

    def __exit__(self, *exc: Any) -> None:
        self.recorder.__exit__(*exc)

    def write(
        self,
        timestamp_ns: int,
        frames: Mapping[str, Frame],
        truth_mm: Mapping[str, np.ndarray | Sequence[float]] | None = None,
        visible: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        """Write the frames of one instant (each with ``timestamp_ns``), its world ground truth and, given,
        the targets each camera sees (``/ground_truth/visibility``)."""
        t = fmt.check_timestamp(timestamp_ns)
        unknown = sorted(set(frames) - set(self.poses))
        if unknown:
            raise InputError(f"camera {unknown[0]!r} has no pose; the rig has {', '.join(self.poses)}")
        if not self._posed:
            for name, pose in self.poses.items():
                self.recorder.write_protobuf(fmt.TF_TOPIC, fmt.encode_transform(name, pose, t), t)
            self._posed = True
        for name in self.poses:
            frame = frames.get(name)
            if frame is not None:
                if frame.timestamp_ns != t:
                    raise InputError(f"camera {name} frame has timestamp_ns={frame.timestamp_ns}, the instant is {t}")
                self.recorder.write(frame, name)
        for target, xyz in (truth_mm or {}).items():
            self.recorder.write_json(
                fmt.WORLD_TRUTH_TOPIC, fmt.WORLD_POINT_SCHEMA, fmt.encode_world_point(target, xyz), t
            )
        if visible is not None:
            self.recorder.write_json(fmt.VISIBILITY_TOPIC, fmt.VISIBILITY_SCHEMA, fmt.encode_visibility(t, visible), t)
        self.sets_written += 1


# --------------------------------------------------------------------------- reading


def _tagged(
    replay: McapReplay, k: int, name: str, instant: Mapping[int, int] | None = None
) -> Iterator[tuple[int, int, str, Frame]]:
    """``(instant, camera number, camera, frame)`` of each frame of ``replay`` (for ``heapq.merge``)."""
    for frame in replay:
        t = frame.timestamp_ns
        yield (t if instant is None else instant[t]), k, name, frame


class RigReplay:
    """A multi-camera recording as frame sets (a context manager).

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.

    Attributes (once open)
    ----------------------
    cameras : tuple of str
        In the order of the recording's ``cameras`` metadata, else sorted.
    poses : dict of str to CameraPose
    replays : dict of str to McapReplay
        One replay per camera (their ``stats`` say what each lost).
    timestamps : ndarray int64
        The instants: every time at which some camera has a frame.
    visibility : dict of int to (dict of str to tuple of str), or None
        Per instant (ns), the targets each camera sees (``/ground_truth/visibility``);
        None when the recording has no such topic.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.cameras: tuple[str, ...] = ()
        self.poses: dict[str, CameraPose] = {}
        self.replays: dict[str, McapReplay] = {}
        self.timestamps = np.zeros(0, np.int64)
        self.notes: list[str] = []
        self._truth: dict[int, dict[str, np.ndarray]] | None = None
        self.visibility: dict[int, dict[str, tuple[str, ...]]] | None = None

    def __enter__(self) -> RigReplay:
        try:
            self.open()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def open(self) -> None:
        """Find the cameras, read their poses from ``/tf`` and open one replay per camera.

        Raises
        ------
        RecordingError
            When the file holds no ``/<camera>/camera/color`` topic, a camera has no pose
            (or several different ones) on ``/tf``, or a camera's topics break the convention.
        """
        with McapTopics(self.path) as topics:
            found = sorted(m.group(1) for t in topics.topics if (m := _CAMERA_COLOR.match(t)))
            if not found:
                listed = ", ".join(sorted(topics.topics)) or "none"
                raise RecordingError(
                    f"{self.path} is not a multi-camera recording: no /<camera>{fmt.COLOR_TOPIC} topic "
                    f"(topics present: {listed})"
                )
            order = [c for c in topics.metadata().get(CAMERAS_KEY, "").split(",") if c in found]
            self.cameras = tuple(order + [c for c in found if c not in order])
            self.poses = self._read_poses(topics)
            self._truth = self._read_truth(topics)
            self.visibility = self._read_visibility(topics)
            self.notes += topics.stats.notes
        for name in self.cameras:
            self.replays[name] = McapReplay(self.path, camera=name).__enter__()
        self.timestamps = np.unique(np.concatenate([r.timestamps for r in self.replays.values()]))

    def close(self) -> None:
        """Close every camera's replay; safe to call twice."""
        for replay in self.replays.values():
            replay.__exit__(None, None, None)
        self.replays = {}

    def _read_poses(self, topics: McapTopics) -> dict[str, CameraPose]:
        seen: dict[str, set[CameraPose]] = {}
        for t, _encoding, data in topics.messages(fmt.TF_TOPIC):
            parent, child, pose = fmt.decode_transform(data, f"{fmt.TF_TOPIC} at t={t} ns")
            if parent == WORLD_FRAME and child in self.cameras:
                seen.setdefault(child, set()).add(pose)
        poses = {}
        meta = topics.metadata()
        for name in self.cameras:
            found = seen.get(name, set())
            if not found and POSE_KEY_PREFIX + name in meta:
                found = {_pose_from_metadata(meta[POSE_KEY_PREFIX + name], f"{self.path} metadata pose_{name}")}
                self.notes.append(f"camera {name}'s pose taken from the recording metadata (none on {fmt.TF_TOPIC})")
            if not found:
                raise RecordingError(
                    f"{self.path}: camera {name} has no pose: expected a {fmt.FRAME_TRANSFORM} "
                    f"{WORLD_FRAME} -> {name} on {fmt.TF_TOPIC}"
                )
            if len(found) > 1:
                raise RecordingError(
                    f"{self.path}: camera {name} has {len(found)} different poses on {fmt.TF_TOPIC}; "
                    "a rig's poses must be static"
                )
            poses[name] = found.pop()
        return poses

    @staticmethod
    def _read_truth(topics: McapTopics) -> dict[int, dict[str, np.ndarray]] | None:
        messages = topics.messages(fmt.WORLD_TRUTH_TOPIC)
        if not messages:
            return None
        truth: dict[int, dict[str, np.ndarray]] = {}
        for t, _encoding, data in messages:
            where = f"{fmt.WORLD_TRUTH_TOPIC} at t={t} ns"
            target, xyz = fmt.decode_world_point(fmt.decode_json(data, where), where)
            truth.setdefault(t, {})[target] = xyz
        return truth

    @staticmethod
    def _read_visibility(topics: McapTopics) -> dict[int, dict[str, tuple[str, ...]]] | None:
        messages = topics.messages(fmt.VISIBILITY_TOPIC)
        if not messages:
            return None
        return {
            t: fmt.decode_visibility(fmt.decode_json(data, where), where)
            for t, _encoding, data in messages
            for where in [f"{fmt.VISIBILITY_TOPIC} at t={t} ns"]
        }

    def __len__(self) -> int:
        return len(self.timestamps)

    def _set(self, index: int, t: int, frames: Mapping[str, Frame]) -> FrameSet:
        views = {name: CameraView(name, frames[name], self.poses[name]) for name in self.cameras if name in frames}
        truth = None if self._truth is None else self._truth.get(t, {})
        return FrameSet(index, t, views, truth, all(v.frame.background for v in views.values()))

    def frameset(self, index: int) -> FrameSet:
        """The frame set of instant ``index`` (random access)."""
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < len(self):
            raise InputError(f"frame set index must be an int in [0, {len(self)}), got {index!r}")
        t = int(self.timestamps[index])
        frames = {}
        for name, replay in self.replays.items():
            k = int(np.searchsorted(replay.timestamps, t))
            if k < len(replay) and int(replay.timestamps[k]) == t:
                frames[name] = replay.frame(k)
        return self._set(int(index), t, frames)

    def __iter__(self) -> Iterator[FrameSet]:
        """Every frame set in time order (each camera's frames streamed once)."""
        streams = [_tagged(self.replays[name], k, name) for k, name in enumerate(self.cameras)]
        index = {int(t): i for i, t in enumerate(self.timestamps)}
        pending: dict[str, Frame] = {}
        current: int | None = None
        for t, _k, name, frame in heapq.merge(*streams, key=lambda item: (item[0], item[1])):
            if current is not None and t != current:
                yield self._set(index[current], current, pending)
                pending = {}
            current = t
            pending[name] = frame
        if current is not None:
            yield self._set(index[current], current, pending)

    def info(self) -> dict[str, Any]:
        """The rig: per camera its resolution, intrinsics, frames, depth and pose; the instants and complete sets."""
        counts = np.zeros(len(self.timestamps), np.int64)
        cameras = []
        first = self.replays[self.cameras[0]].info()
        for name in self.cameras:
            replay = self.replays[name]
            counts += np.isin(self.timestamps, replay.timestamps)
            info = replay.info()
            pose = self.poses[name]
            cameras.append(
                {
                    "name": name,
                    "width": info.width,
                    "height": info.height,
                    "intrinsics": info.intrinsics,
                    "frames": info.frames,
                    "color_format": info.color_format,
                    "depth_format": info.depth_format,
                    "missing_depth": info.missing_depth,
                    "translation_mm": [float(v) for v in pose.translation_mm],
                    "rotation_xyzw": [float(v) for v in pose.quaternion()],
                }
            )
        return {
            "path": str(self.path),
            "size_bytes": first.size_bytes,
            "library": first.library,
            "truncated": first.truncated,
            "metadata": first.metadata,
            "topics": [dataclasses.asdict(t) for t in first.topics],
            "cameras": cameras,
            "instants": int(len(self.timestamps)),
            "complete_sets": int(np.count_nonzero(counts == len(self.cameras))),
            "world_truth": self._truth is not None,
        }


def is_rig(path: str | Path) -> bool:
    """Whether ``path`` is a multi-camera recording (has a ``/<camera>/camera/color`` topic)."""
    with McapTopics(path) as topics:
        return any(_CAMERA_COLOR.match(t) for t in topics.topics)


# --------------------------------------------------------------------------- merging


def match_times(reference: np.ndarray, times: np.ndarray, tolerance_ns: int) -> tuple[np.ndarray, int]:
    """Instants for ``times`` (one camera's frame times) against the ``reference`` camera's.

    Each frame goes to the nearest reference time within ``tolerance_ns`` that no
    nearer frame of the same camera claims; a frame left without one keeps its
    own time (an instant the reference camera has no frame at).

    Returns
    -------
    instants : ndarray int64, shape of ``times``
        Increasing when ``times`` is.
    unmatched : int
        How many frames kept their own time.
    """
    reference = np.asarray(reference, np.int64)
    times = np.asarray(times, np.int64)
    if not len(reference) or not len(times):
        return times.copy(), len(times)
    k = (
        np.clip(np.searchsorted(reference, times), 1, len(reference) - 1)
        if len(reference) > 1
        else np.zeros(len(times), np.int64)
    )
    left, right = reference[k - 1] if len(reference) > 1 else reference[k], reference[k]
    nearest = np.where(np.abs(times - left) <= np.abs(right - times), left, right)
    dist = np.abs(times - nearest)
    ok = dist <= tolerance_ns
    order = np.lexsort((dist, nearest))  # by reference time, nearest frame first
    first = np.ones(len(order), bool)
    first[1:] = nearest[order][1:] != nearest[order][:-1]
    winner = np.zeros(len(times), bool)
    winner[order[first]] = True
    take = ok & winner
    return np.where(take, nearest, times), int(np.count_nonzero(~take))


def merge(
    inputs: Sequence[str | Path],
    poses: Mapping[str, CameraPose],
    out: str | Path,
    *,
    tolerance_ns: int | None = None,
    recorder_kwargs: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Combine single-camera recordings (camera ``i`` = ``inputs[i]``) into one multi-camera recording.

    The first input is the reference clock: another camera's frame joins the
    reference frame nearest in time within ``tolerance_ns`` (default half the
    reference's frame period) and takes its timestamp; the others keep their own.

    Returns
    -------
    dict
        ``sets`` written, per camera ``frames`` and ``unmatched``, ``background_unflagged`` and ``notes``.
    """
    names = list(poses)
    if len(names) != len(inputs):
        raise InputError(
            f"the extrinsics name {len(names)} camera(s) ({', '.join(names)}) but {len(inputs)} recording(s) were given"
        )
    report: dict[str, Any] = {"cameras": {}, "notes": []}
    with contextlib.ExitStack() as stack:
        replays = [stack.enter_context(McapReplay(path)) for path in inputs]
        reference = replays[0].timestamps
        if tolerance_ns is None:
            period = np.median(np.diff(reference)) if len(reference) > 1 else 0
            tolerance_ns = int(period // 2)
        instants = {}
        for name, replay in zip(names, replays, strict=True):
            new, unmatched = match_times(reference, replay.timestamps, tolerance_ns)
            if len(new) > 1 and not (np.diff(new) > 0).all():
                raise InputError(f"{replay.path}: frames do not keep their order when matched to {inputs[0]}")
            instants[name] = new
            report["cameras"][name] = {"input": str(replay.path), "frames": len(new), "unmatched": unmatched}
        meta = {"source": "merge:" + ",".join(Path(p).name for p in inputs)}
        to_instant = {
            name: dict(zip(replay.timestamps.tolist(), instants[name].tolist(), strict=True))
            for name, replay in zip(names, replays, strict=True)
        }
        streams = [
            _tagged(replay, k, name, to_instant[name])
            for k, (name, replay) in enumerate(zip(names, replays, strict=True))
        ]
        foreground = False
        unflagged = 0

        def flush(t: int, frames: dict[str, Frame]) -> None:
            # an instant is a background one only while every camera still shows the empty scene
            nonlocal foreground, unflagged
            foreground = foreground or not all(f.background for f in frames.values())
            if foreground:
                unflagged += sum(f.background for f in frames.values())
            rig.write(
                t, {n: dataclasses.replace(f, timestamp_ns=t, background=not foreground) for n, f in frames.items()}
            )

        with RigRecorder(out, poses, metadata=meta, **dict(recorder_kwargs or {})) as rig:
            pending: dict[str, Frame] = {}
            current: int | None = None
            for t, _k, name, frame in heapq.merge(*streams, key=lambda item: (item[0], item[1])):
                if current is not None and t != current:
                    flush(current, pending)
                    pending = {}
                current = t
                pending[name] = frame
            if current is not None:
                flush(current, pending)
            report["sets"] = rig.sets_written
        report["background_unflagged"] = unflagged
        for name, replay in zip(names, replays, strict=True):
            summary = replay.stats.loss_summary()
            if summary:
                report["notes"].append(f"{name} ({replay.path}): {summary}")
    return report
