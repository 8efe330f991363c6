"""``fusion-pf track``: track the palm through a recording or a live source (paper 003)."""

from __future__ import annotations

import argparse
from pathlib import Path

from drivers import SOURCE_SPECS

NAME = "track"
HELP = "track the palm (data-fusion particle filter or Kalman baseline) and write MCAP/CSV outputs"
DESCRIPTION = (
    "Track the palm centre through SOURCE by fusing the colour cue, the depth cue (paper 003 "
    "§3.5, background subtraction in a window around a prior) and the skeleton joint in a "
    "particle filter (or the Kalman baseline). OUT.mcap gets the input topics plus "
    "/tracker/estimate, /tracker/cues, /tracker/overlay and /tracker/particles "
    "(docs/recording-format.md, 'Tracker outputs'); --csv writes one row per tracked frame "
    "(docs/architecture.md, 'CSV'). The background model comes from --background, else the "
    "recording's own background frames, else the median of its first --background-k frames. "
    "Pixels are colour-image pixels, 3-D points camera-frame millimetres. The same --seed gives "
    "a byte-identical CSV (latency columns are left empty unless --csv-latency). Outputs are "
    "finalised on Ctrl-C (exit 130) and on errors (exit 2)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf track``.

    Numeric options are parsed in :func:`run` so a bad value gives one
    ``fusion-pf: error:`` line naming the value and the valid range.
    """
    p.add_argument("source", metavar="SOURCE", help=f"what to track: {SOURCE_SPECS}")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT.mcap",
                   help="MCAP file to write (input topics + tracker topics)")
    p.add_argument("--csv", type=Path, metavar="OUT.csv", help="also write the per-frame CSV")
    p.add_argument("--csv-latency", action="store_true",
                   help="fill the CSV's latency_*_ms columns (wall time: the CSV is then not byte-identical across runs)")
    p.add_argument("--filter", default="pf", metavar="pf|kf", help="particle filter or Kalman baseline")
    p.add_argument("--particles", default="100", metavar="N", help="particle count, 1-100000")
    p.add_argument("--seed", default="0", metavar="S", help="seed of the particle filter (and of --cue-noise), >= 0")
    p.add_argument("--likelihood", default="auto", metavar="auto|gaussian|robust",
                   help="particle-filter likelihood: paper eq. 6 or Gaussian + outlier mixture; "
                        "auto = robust for pf, gaussian for kf")
    p.add_argument("--joint", default="right_hand", metavar="NAME", help="skeleton joint used as the skeleton cue")
    p.add_argument("--background", type=Path, metavar="FILE.mcap",
                   help="empty-scene recording for the background model")
    p.add_argument("--background-k", default=argparse.SUPPRESS, metavar="K",
                   help="frames of the running-median background when there is no empty scene (default: 30)")
    p.add_argument("--roi-prior", default="auto", metavar="auto|filter|skeleton",
                   help="centre of the cue window: the skeleton joint (paper), the filter prediction, or auto: the joint while confident, else the prediction")
    p.add_argument("--noise", default=argparse.SUPPRESS, metavar="SRC=PX,...",
                   help="measurement noise sigma per source in px, e.g. colour=4,depth=8,skeleton=20 "
                        "(default: colour=5,depth=6,skeleton=40, tuned on synthetic scenes)")
    p.add_argument("--process-noise", default=argparse.SUPPRESS, metavar="POS,VEL",
                   help="process noise std per frame: position px, velocity px/frame (default: 3,1)")
    p.add_argument("--sources", default="colour,depth,skeleton", metavar="SRC,...",
                   help="sources the filter fuses (all cues are still computed and written)")
    p.add_argument("--cue-noise", default=argparse.SUPPRESS, metavar="SRC=PX,...",
                   help="add Gaussian noise (px) to cue positions, as paper 003 §4.2-4.3 does, e.g. "
                        "colour=4,depth=4 (default: none)")
    p.add_argument("--export-ply", type=Path, metavar="DIR",
                   help="write the ROI point cloud of every tracked frame (mm, camera frame) as DIR/frame_NNNNNN.ply")
    p.add_argument("--color-format", default="auto", metavar="auto|raw|jpeg|png",
                   help="colour encoding in OUT.mcap (auto: as the input recording, raw otherwise)")
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap / OUT.csv if they exist")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _int(name: str, text: str, lo: int, hi: int) -> int:
    from fusion_pf.errors import InputError

    try:
        value = int(text)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {text!r}") from None
    if not lo <= value <= hi:
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {value}")
    return value


def _choice(name: str, text: str, choices: tuple[str, ...]) -> str:
    from fusion_pf.errors import InputError

    if text not in choices:
        raise InputError(f"{name} must be one of {', '.join(choices)}, got {text!r}")
    return text


def _pairs(name: str, text: str) -> dict[str, float]:
    """``"colour=4,depth=8"`` -> ``{"colour": 4.0, "depth": 8.0}`` (values checked by TrackConfig)."""
    from fusion_pf.errors import InputError

    out: dict[str, float] = {}
    for item in filter(None, text.split(",")):
        key, sep, value = item.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = None
        if not sep or not key.strip() or number is None:
            raise InputError(f"{name} must look like colour=PX,depth=PX,skeleton=PX, got {text!r}")
        out[key.strip()] = number
    return out


def config_from_args(args: argparse.Namespace):
    """The :class:`~fusion_pf.track.TrackConfig` of the command line (InputError on bad values)."""
    from fusion_pf.errors import InputError
    from fusion_pf.track import FILTERS, ROI_PRIORS, TrackConfig

    kwargs: dict = {
        "filter": _choice("--filter", args.filter, FILTERS),
        "particles": _int("--particles", args.particles, 1, 100_000),
        "seed": _int("--seed", args.seed, 0, 2**63 - 1),
        "likelihood": None if args.likelihood == "auto" else _choice("--likelihood", args.likelihood, ("auto", "gaussian", "robust")),
        "joint": args.joint,
        "roi_prior": _choice("--roi-prior", args.roi_prior, ROI_PRIORS),
        "sources": tuple(s.strip() for s in args.sources.split(",") if s.strip()),
        "background": args.background,
    }
    if "background_k" in args:
        kwargs["background_k"] = _int("--background-k", args.background_k, 1, 10_000)
    if "noise" in args:
        kwargs["noise_px"] = _pairs("--noise", args.noise)
    if "cue_noise" in args:
        kwargs["cue_noise_px"] = _pairs("--cue-noise", args.cue_noise)
    if "process_noise" in args:
        parts = args.process_noise.split(",")
        try:
            kwargs["process_noise"] = tuple(float(x) for x in parts)
        except ValueError:
            parts = []
        if len(parts) != 2:
            raise InputError(f"--process-noise must be POS,VEL in px and px/frame, got {args.process_noise!r}")
    if kwargs["filter"] == "kf" and kwargs["likelihood"] == "robust":
        raise InputError("--likelihood robust needs --filter pf (the Kalman filter is Gaussian only)")
    return TrackConfig(**kwargs)


def _check_outputs(args: argparse.Namespace) -> None:
    from fusion_pf.errors import InputError

    from ._paths import check_output

    outputs = [("output", args.output)] + ([("--csv", args.csv)] if args.csv is not None else [])
    for what, out in outputs:
        check_output(out, force=args.force, what=what, inputs=(args.source, args.background))
    if args.csv is not None and args.csv.resolve() == args.output.resolve():
        raise InputError(f"--csv {args.csv} is the same file as the output MCAP")
    if args.export_ply is not None:
        if args.export_ply.exists() and not args.export_ply.is_dir():
            raise InputError(f"--export-ply {args.export_ply} is a file; expected a directory")
        if not args.export_ply.parent.is_dir():
            raise InputError(f"--export-ply parent directory {args.export_ply.parent} does not exist")
    if args.background is not None and not args.background.is_file():
        raise InputError(f"--background {args.background} does not exist; expected an empty-scene .mcap recording")


def _recorder_options(src, args: argparse.Namespace) -> dict:
    """Colour/depth encodings and metadata of the output, following the input recording."""
    from fusion_pf.errors import InputError

    options: dict = {"color_format": "raw", "depth_format": "raw", "metadata": {"source": str(args.source)}}
    info = src.info() if callable(getattr(src, "info", None)) else None
    if info is not None:
        options["color_format"] = {"jpeg": "jpeg", "png": "png"}.get(info.color_format or "", "raw")
        options["depth_format"] = "png" if info.depth_format == "png" else "raw"
        keep = {k: v for k, v in info.metadata.items() if k not in ("background_frames", "format_version", "writer")}
        options["metadata"] = {**keep, **options["metadata"]}
    elif callable(getattr(src, "metadata", None)):
        options["metadata"] = {**src.metadata(), **options["metadata"]}
    if args.color_format != "auto":
        options["color_format"] = _choice("--color-format", args.color_format, ("auto", "raw", "jpeg", "png"))
    for key, value in options["metadata"].items():
        if not isinstance(value, str):
            raise InputError(f"source metadata {key!r} must be a string, got {value!r}")
    return options


def run(args: argparse.Namespace) -> int:
    """Track SOURCE, writing OUT.mcap (and the CSV / PLY files); returns the exit status."""
    import json
    import sys
    import time
    from contextlib import ExitStack
    from dataclasses import asdict

    from tqdm import tqdm

    from drivers import ReplaySource, open_source
    from drivers.mcap_record import McapRecorder
    from fusion_pf.geometry import write_roi_ply
    from fusion_pf.signals import sigint_deferred
    from fusion_pf.track import TrackCsv, TrackerTopics, track

    config = config_from_args(args)
    _check_outputs(args)
    if args.export_ply is not None:
        args.export_ply.mkdir(exist_ok=True)
    tracked = background = 0
    with open_source(args.source) as src, ExitStack() as stack:
        options = _recorder_options(src, args)
        settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(config).items()}
        options["metadata"]["tracker"] = json.dumps(settings, sort_keys=True)
        recorder = stack.enter_context(McapRecorder(args.output, **options))
        table = stack.enter_context(TrackCsv(args.csv, latency=args.csv_latency)) if args.csv is not None else None
        total = len(src) if isinstance(src, ReplaySource) else None
        bar = stack.enter_context(
            tqdm(total=total, unit="frame", desc=src.describe(), disable=True if args.no_progress else None, file=sys.stderr)
        )
        topics = TrackerTopics(recorder, config)
        for result in track(src, config):
            with sigint_deferred():
                t0 = time.perf_counter_ns()
                recorder.write(result.source_frame)
                topics.write(result)
                if args.export_ply is not None and not result.background and result.roi is not None \
                        and result.source_frame.depth is not None:
                    r = result.roi
                    write_roi_ply(args.export_ply / f"frame_{result.frame:06d}.ply", result.source_frame,
                                  (r.x0, r.y0, r.x1, r.y1), palm=result.xyz_mm)
                result.latency_ns["sinks"] = time.perf_counter_ns() - t0
                if table is not None:
                    table.write(result)
            result.source_frame = None
            background += result.background
            tracked += not result.background
            bar.update(1)
    print(f"tracked {tracked} frames ({background} background) of {args.source} -> {args.output}"
          + (f", {args.csv}" if args.csv is not None else ""), file=sys.stderr)
    return 0
