"""``fusion-pf synth``: render the synthetic scene into an MCAP recording."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from dataclasses import dataclass
from pathlib import Path

from drivers.encoding import EncodingOptions
from drivers.mcap_format import EVENT_SCHEMA, GROUND_TRUTH_EVENTS_TOPIC
from drivers.synth import DEPTH_MODELS, MAX_FRAMES, MAX_SIZE, MIN_SIZE, SCRIPTS, VARIATIONS, SynthSource
from drivers.synth_rig import MAX_CAMERAS, SynthRig, parse_occlusions
from fusion_pf.errors import InputError
from fusion_pf.options import add_options, from_args, option, validate
from fusion_pf.text import printable

from ._options import parse_size, show_size, size_check

NAME = "synth"
HELP = "render the synthetic RGB-D scene (with skeleton and ground truth) into an MCAP file"
DESCRIPTION = (
    "Render N frames of the seeded synthetic scene (drivers/synth.py: a person in dark clothes "
    "whose bare right palm repeatedly passes in front of the torso, stereo-like depth, a "
    "Kinect-like skeleton that fails during self-occlusion, ground truth on /ground_truth/palm) "
    "into OUT.mcap. The first K frames show the empty scene (background frames). The same seed "
    "and options give the same frames. With --cameras N (N >= 2) the scene is seen by N calibrated "
    "cameras (drivers/synth_rig.py) and OUT.mcap is a multi-camera recording: each camera's topics "
    "under /camN, the poses on /tf and in the metadata, world ground truth per target on "
    "/ground_truth/world. --board renders the same rig's calibration sequence instead: a ChArUco "
    "board where the person stands, for fusion-pf calibrate (the same seed gives the same poses)."
)


def _check_occlude(label: str, value: str) -> str:
    try:
        parse_occlusions(value)
    except InputError as exc:
        raise InputError(f"{label}: {exc}") from None
    return value


#: The synthetic scene's own defaults (``SynthSource``'s keyword arguments): defined once, there.
_SCENE = {name: p.default for name, p in inspect.signature(SynthSource).parameters.items()}


@dataclass(frozen=True)
class SynthOptions:
    """The scene options of ``fusion-pf synth`` (validated on construction)."""

    frames: int = option(
        _SCENE["frames"],
        kind="int",
        lo=1,
        hi=MAX_FRAMES,
        metavar="N",
        help="frames to render, background frames included",
    )
    seed: int = option(_SCENE["seed"], kind="int", lo=0, hi=2**63 - 1, metavar="S", help="scene and noise seed")
    background_frames: int = option(
        _SCENE["background_frames"],
        kind="int",
        lo=0,
        hi=MAX_FRAMES,
        metavar="K",
        help="empty-scene frames at the start",
    )
    size: tuple[int, int] = option(
        _SCENE["size"],
        parse=parse_size,
        check=size_check(MIN_SIZE, MAX_SIZE),
        show=show_size,
        metavar="WxH",
        unit="px",
        help="image size",
    )
    fps: float = option(
        _SCENE["fps"], kind="float", lo=0.001, hi=1000.0, metavar="F", help="frame rate (timestamps 1/F s apart)"
    )
    depth_model: str = option(
        _SCENE["depth_model"],
        choices=DEPTH_MODELS,
        help="depth sensor model: realistic stereo artefacts (noise ~ z^2, 1/8 px disparity steps, "
        "flying pixels and holes at depth steps, speckle holes, range limits), or basic "
        "(the model recordings/sample.mcap was made with)",
    )
    hands: int = option(
        _SCENE["hands"],
        kind="int",
        lo=1,
        hi=2,
        metavar="H",
        help="1: one palm sweeping in front of the torso; 2: both hands washing (by default they join twice "
        "and cross once every 300 frames; see --joins, --crossings, --timing), ground truth per target "
        "(right_hand, left_hand, head)",
    )
    script: str = option(
        _SCENE["script"],
        choices=SCRIPTS,
        help="events: the scripted two-hand scene (needs --hands 2; seeded timing and places; with --cameras seen by "
        "every camera): a ball picked up by the right hand and passed to the left while the hands join, the right "
        "hand at the head, a second join; its true events on /ground_truth/events",
    )

    depth_noise: float = option(
        _SCENE["depth_noise"],
        kind="float",
        lo=VARIATIONS["depth_noise"][1],
        hi=VARIATIONS["depth_noise"][2],
        help="factor on the depth sensor's disparity noise",
    )
    hand_front: float = option(
        _SCENE["hand_front"],
        kind="float",
        lo=VARIATIONS["hand_front"][1],
        hi=VARIATIONS["hand_front"][2],
        unit="m",
        help="the palm's smallest distance in front of the torso (it sweeps 0.1 m farther)",
    )
    lighting: float = option(
        _SCENE["lighting"],
        kind="float",
        lo=VARIATIONS["lighting"][1],
        hi=VARIATIONS["lighting"][2],
        help="factor on the illumination drift, gradient and flicker",
    )
    skin_tone: float = option(
        _SCENE["skin_tone"],
        kind="float",
        lo=VARIATIONS["skin_tone"][1],
        hi=VARIATIONS["skin_tone"][2],
        help="skin colour from light (0) to dark (1)",
    )
    skeleton_bias: float = option(
        _SCENE["skeleton_bias"],
        kind="float",
        lo=VARIATIONS["skeleton_bias"][1],
        hi=VARIATIONS["skeleton_bias"][2],
        help="factor on the skeleton hand's failure (bias toward the torso and jitter) while the palm "
        "is over the body; 0: a skeleton that never fails",
    )
    clothing: float = option(
        _SCENE["clothing"],
        kind="float",
        lo=VARIATIONS["clothing"][1],
        hi=VARIATIONS["clothing"][2],
        help="shirt colour: 0 navy, 1 skin-like beige, 2 wood-like brown, 3 red, 4 light grey, 5 dark green; "
        "fractions blend the two neighbours",
    )
    clutter: int = option(
        _SCENE["clutter"],
        kind="int",
        lo=int(VARIATIONS["clutter"][1]),
        hi=int(VARIATIONS["clutter"][2]),
        metavar="N",
        help="static objects in the room (boxes and round shapes; every third skin-coloured, every second "
        "at hand depth beside the person), placed from the seed",
    )
    away: int = option(
        _SCENE["away"],
        kind="int",
        lo=int(VARIATIONS["away"][1]),
        hi=int(VARIATIONS["away"][2]),
        metavar="N",
        help="the person leaves the view for N of every 100 frames (the empty room, not background frames: no "
        "skeleton, no ground truth; phase from the seed): re-acquisition, acquisition-dominated recordings; "
        "one palm only",
    )
    hand_distance: float = option(
        _SCENE["hand_distance"],
        kind="float",
        lo=VARIATIONS["hand_distance"][1],
        hi=VARIATIONS["hand_distance"][2],
        unit="m",
        help="--hands 2: the palms' horizontal distance while apart",
    )
    joins: int = option(
        _SCENE["joins"],
        kind="int",
        lo=int(VARIATIONS["joins"][1]),
        hi=int(VARIATIONS["joins"][2]),
        metavar="N",
        help="--hands 2: times the hands join (palms 4 cm apart, rubbing) per cycle",
    )
    crossings: int = option(
        _SCENE["crossings"],
        kind="int",
        lo=int(VARIATIONS["crossings"][1]),
        hi=int(VARIATIONS["crossings"][2]),
        metavar="N",
        help="--hands 2: times the hands cross per cycle (an odd number: the next cycle is mirrored)",
    )
    cross_height: float = option(
        _SCENE["cross_height"],
        kind="float",
        lo=VARIATIONS["cross_height"][1],
        hi=VARIATIONS["cross_height"][2],
        unit="m",
        help="--hands 2: how far the right palm passes above the left one while crossing",
    )
    timing: int = option(
        _SCENE["timing"],
        kind="int",
        lo=int(VARIATIONS["timing"][1]),
        hi=int(VARIATIONS["timing"][2]),
        metavar="T",
        help="--hands 2: 0 fixed phase lengths; 1 the order of joins and crossings and every hold, approach "
        "and crossing length drawn from the seed",
    )
    cameras: int = option(
        1,
        kind="int",
        lo=1,
        hi=MAX_CAMERAS,
        metavar="N",
        help="cameras seeing the scene; N >= 2 writes a multi-camera recording (poses on /tf, world ground truth)",
    )
    colour_only: int = option(
        0,
        kind="int",
        lo=0,
        hi=MAX_CAMERAS,
        metavar="K",
        help="with --cameras: the last K cameras have no depth (colour-only cameras)",
    )
    occlude: str = option(
        "none",
        kind="str",
        check=_check_occlude,
        metavar="SPEC",
        help="with --cameras: periods in which a card in front of one camera hides a target from it, "
        "CAM:TARGET:START-END[,...] (frames, inclusive; e.g. cam1:right_hand:40-80), auto (each hand once, "
        "camera and period from the seed) or none; the targets each camera sees go on /ground_truth/visibility",
    )
    board: bool = option(
        False,
        kind="bool",
        help="with --cameras: the rig's calibration sequence (a ChArUco board in the empty room) instead of the person",
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.colour_only and self.cameras < 2:
            raise InputError("--colour-only describes cameras of a rig; it needs --cameras 2 or more")
        if self.colour_only > self.cameras:
            raise InputError(
                f"colour_only (--colour-only) must be in [0, cameras {self.cameras}], got {self.colour_only}"
            )
        if self.occlude != "none" and self.cameras < 2:
            raise InputError("--occlude hides targets from cameras of a rig; it needs --cameras 2 or more")
        if self.script != "none" and self.hands != 2:
            raise InputError(
                f"--script {self.script} is a two-hand scene; it needs --hands 2, got --hands {self.hands}"
            )
        if self.script != "none" and self.board:
            raise InputError(f"--script {self.script} acts the person's script; --board renders no person")
        if self.board and self.cameras < 2:
            raise InputError("--board renders a rig's calibration sequence; it needs --cameras 2 or more")
        if self.background_frames > self.frames:
            raise InputError(
                f"background_frames (--background-frames) must be in [0, frames {self.frames}], "
                f"got {self.background_frames}"
            )


#: The config classes whose flags the command registers.
CONFIGS = (SynthOptions, EncodingOptions)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf synth``."""
    p.add_argument("output", type=Path, metavar="OUT.mcap", help="MCAP file to write")
    add_options(p, SynthOptions)
    add_options(p, EncodingOptions)
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Render and record; the file is finalised even on Ctrl-C."""
    import sys
    import time

    from tqdm import tqdm

    from drivers.mcap_record import McapRecorder

    from ._paths import check_output

    scene = from_args(SynthOptions, args)
    encoding = from_args(EncodingOptions, args)
    options = dataclasses.asdict(scene)
    rig = {name: options.pop(name) for name in ("cameras", "board", "colour_only", "occlude")}
    out: Path = args.output
    check_output(out, force=args.force)
    if rig["cameras"] > 1:
        return _run_rig(SynthRig(rig.pop("cameras"), **rig, **options), encoding, out, args.no_progress)
    source = SynthSource(**options)
    recorder = McapRecorder(out, metadata=source.metadata(), **encoding.recorder_kwargs())
    started = time.monotonic()
    with (
        source,
        recorder,
        tqdm(
            total=len(source),
            unit="frame",
            desc=source.describe(),
            disable=True if args.no_progress else None,
            file=sys.stderr,
        ) as bar,
    ):
        truth = source.true_events()
        for frame in source:
            recorder.write(frame)
            for event in (e for e in truth if e["frame"] == frame.seq):
                recorder.write_json(GROUND_TRUTH_EVENTS_TOPIC, EVENT_SCHEMA, event, event["timestamp_ns"])
            bar.update()
    print(
        f"wrote {recorder.frames_written} frames ({source.background_frames} background) to {printable(out)} "
        f"in {time.monotonic() - started:.1f} s: {recorder.bytes_written} bytes"
    )
    return 0


def _run_rig(rig: SynthRig, encoding: EncodingOptions, out: Path, no_progress: bool) -> int:
    """Render the multi-camera scene into a multi-camera recording."""
    import sys
    import time

    from tqdm import tqdm

    from drivers.rig import RigRecorder

    started = time.monotonic()
    cameras = rig.cameras
    with (
        RigRecorder(out, rig.poses, metadata=rig.metadata(), **encoding.recorder_kwargs()) as recorder,
        tqdm(
            total=len(rig),
            unit="set",
            desc=f"synth rig of {cameras}",
            disable=True if no_progress else None,
            file=sys.stderr,
        ) as bar,
    ):
        events = rig.true_events()
        for index in range(len(rig)):
            frames, visible = rig.render(index)
            truth = rig.truth_mm(index)
            recorder.write(rig.timestamp_ns(index), frames, truth, visible if truth else None)
            for event in (e for e in events if e["frame"] == index):
                recorder.recorder.write_json(GROUND_TRUTH_EVENTS_TOPIC, EVENT_SCHEMA, event, event["timestamp_ns"])
            bar.update()
    print(
        f"wrote {recorder.sets_written} instants of {cameras} cameras ({rig.source.background_frames} background) "
        f"to {out} in {time.monotonic() - started:.1f} s: {recorder.recorder.bytes_written} bytes"
    )
    return 0
