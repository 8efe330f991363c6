"""``fusion-pf annotations``: work with an annotation database (``export``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from fusion_pf.text import printable

NAME = "annotations"
HELP = "export the operator reference (per-frame mean and spread) of an annotation database"
DESCRIPTION = (
    "annotations export DB --csv OUT writes one row per annotated frame: frame, timestamp_ns, "
    "n_operators (operators who did the frame, clicked or 'not visible'), n_not_visible, "
    "mean_u, mean_v (mean of the clicks, the reference of paper 003 §4.1; empty when nobody "
    "saw the palm) and spread_px (mean distance of the clicks to that mean). It also writes "
    "one row per operator (--operators-csv, default OUT with '_operators' before the suffix): "
    "operator, n_frames, n_not_visible, n_compared, mean_dist_to_others_px and "
    "max_dist_to_others_px (distance of the operator's click to the mean of the other "
    "operators' clicks, over frames where both exist) and n_visibility_disagreements. Existing "
    "outputs are refused without --force; the database (and its -wal/-shm files), an MCAP "
    "recording or an SQLite file are never overwritten. The WAL is checkpointed into the database "
    "first. Operator names that a spreadsheet would run as a formula (=, +, -, @) are written "
    "with a leading apostrophe."
)


#: The config classes whose flags the command registers: none, its only flags are paths and switches.
CONFIGS: tuple[type, ...] = ()


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the ``export`` action and its options."""
    sub = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    e = sub.add_parser(
        "export",
        help="write the per-frame reference and per-operator CSVs",
        description=DESCRIPTION,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    e.add_argument("db", type=Path, metavar="DB", help="SQLite file written by fusion-pf annotate")
    e.add_argument("--csv", type=Path, required=True, metavar="OUT", help="per-frame reference CSV")
    e.add_argument(
        "--operators-csv",
        type=Path,
        metavar="OPS",
        help="per-operator CSV; when omitted, OUT with '_operators' before the suffix",
    )
    e.add_argument("--force", action="store_true", help="overwrite existing CSV files")


def operators_path(csv_path: Path) -> Path:
    """Default per-operator CSV next to ``csv_path``: ``ref.csv`` -> ``ref_operators.csv``."""
    return csv_path.with_name(f"{csv_path.stem}_operators{csv_path.suffix or '.csv'}")


def run(args: argparse.Namespace) -> int:
    """Write the CSVs and print one summary line."""
    from fusion_pf.annotate.db import checkpoint, write_operators_csv, write_reference_csv
    from fusion_pf.errors import InputError

    from ._paths import SQLITE_SIDECARS, check_distinct, check_output, input_holding

    if not args.db.is_file():
        raise FileNotFoundError(2, "no such file", str(args.db))
    ops = args.operators_csv or operators_path(args.csv)
    check_distinct([("--csv", args.csv), ("--operators-csv", ops)])
    inputs = [args.db] + [args.db.with_name(args.db.name + suffix) for suffix in SQLITE_SIDECARS]
    for out, what in ((args.csv, "--csv"), (ops, "--operators-csv")):
        other = input_holding(out, inputs) or next((i for i in inputs if out.resolve() == i.resolve()), None)
        if other is not None:
            raise InputError(f"{what} {out} is the annotation database (or its {other.name}); choose a CSV file")
        if out.is_file():
            with open(out, "rb") as fh:
                head = fh.read(16)
            if head.startswith((b"\x89MCAP", b"SQLite format 3")):
                kind = "an MCAP recording" if head.startswith(b"\x89MCAP") else "an SQLite database"
                raise InputError(f"{what} {out} is {kind}, not a CSV; it is never overwritten")
        check_output(out, force=args.force, what=what)
    checkpoint(args.db)
    n_frames = write_reference_csv(args.db, args.csv)
    n_ops = write_operators_csv(args.db, ops)
    print(f"fusion-pf annotations: {n_frames} frames -> {printable(args.csv)}, {n_ops} operators -> {printable(ops)}")
    return 0
