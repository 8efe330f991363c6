"""``fusion-pf annotate``: the multi-operator palm-centre annotation web app."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fusion_pf.annotate.options import ServeOptions
from fusion_pf.options import add_options, from_args

NAME = "annotate"
HELP = "serve a local web page where operators click the palm centre of every frame"
DESCRIPTION = (
    "Serve a local web app (waitress) to annotate REC.mcap: each operator enters a name, "
    "clicks the palm centre (or marks it not visible) on every frame, and sees the other "
    "operators' clicks only after doing the frame. Clicks are committed to the SQLite "
    "database (WAL, synchronous=FULL) before they are acknowledged; one row per operator "
    "and frame, a re-click replaces it. The database is tied to the recording's content (SHA-256): "
    "it refuses any other recording. Binds 127.0.0.1 unless --host says otherwise; requests must "
    "name this server in their Host header (DNS-rebinding protection). Connections are capped per "
    "client address and in all (a new one closes the oldest idle one) and must hand in a complete request "
    "within --idle-timeout, so a flood of idle or trickling connections neither locks operators out nor "
    "crashes the server. On Ctrl-C/SIGTERM the WAL "
    "is checkpointed into the database file. "
    "Keys in the page: left/right = previous/next frame, n = next frame you have not done, "
    "x = not visible, d = depth overlay, +/- = zoom."
)


#: The config classes whose flags the command registers.
CONFIGS = (ServeOptions,)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf annotate``."""
    p.add_argument("recording", type=Path, metavar="REC.mcap", help="recording to annotate")
    p.add_argument("--db", type=Path, required=True, help="SQLite file of the clicks (created if missing)")
    add_options(p, ServeOptions)


def run(args: argparse.Namespace) -> int:
    """Open the recording and the database, then serve until Ctrl-C."""
    import ipaddress

    from drivers.mcap_replay import McapReplay
    from fusion_pf.annotate.db import AnnotationDB, recording_sha256
    from fusion_pf.annotate.frames import FrameImages, ReplayProvider
    from fusion_pf.annotate.server import create_app, serve
    from fusion_pf.errors import InputError
    from fusion_pf.signals import stop_on_terminate

    from ._paths import SQLITE_SIDECARS, check_not_input

    opts = from_args(ServeOptions, args)
    if not args.recording.is_file():
        raise FileNotFoundError(2, "no such file", str(args.recording))
    if args.db.is_dir():
        raise InputError(f"--db {args.db} is a directory; expected an SQLite file name")
    if not args.db.parent.is_dir():
        raise InputError(f"--db {args.db}: the folder {args.db.parent} does not exist")
    for suffix in ("", *SQLITE_SIDECARS):
        check_not_input(args.db.with_name(args.db.name + suffix), (args.recording,), "--db")
    try:
        loopback = ipaddress.ip_address(opts.host).is_loopback
    except ValueError:
        loopback = opts.host == "localhost"
    if not loopback:
        print(
            f"fusion-pf annotate: warning: binding {opts.host}, the annotator is reachable from "
            "the network without any authentication",
            file=sys.stderr,
        )
    with McapReplay(args.recording) as replay:
        images = FrameImages(ReplayProvider(replay), color_format=opts.image_format, cache_size=opts.cache)
        first = images.meta(0)
        db = AnnotationDB(
            args.db,
            recording=args.recording.name,
            n_frames=images.n_frames,
            width=first.width,
            height=first.height,
            sha256=recording_sha256(args.recording),
            timestamps=replay.timestamps.tolist(),
        )
        try:
            app = create_app(images, db, recording=args.recording.name)

            def ready(url: str) -> None:
                print(
                    f"fusion-pf annotate: {images.n_frames} frames of {args.recording.name}, "
                    f"clicks in {args.db}; open {url}",
                    flush=True,
                )

            with stop_on_terminate():
                serve(app, opts, on_ready=ready)
        finally:
            db.close()
    return 0
