"""Fuzz campaign over damaged recordings: does every reader say what it lost?

A small synthetic recording (with leading background frames) is written, then
mutated (seeded): truncation, bit flips, zeroed blocks, removed byte ranges,
duplicated byte ranges, junk appended, and byte ranges removed before and
inside the background section (from the metadata records at the start of the
file to the end of the last chunk holding a background frame). Each mutant
goes through three checks, each in a worker process with a time limit:

``info``
    ``fusion-pf info --verify --json FILE`` (in the worker, through ``cli.main``).
``replay``
    ``McapReplay(FILE)``: iterate every frame; each frame read is identified
    by its timestamp in the original recording, so its ``index`` and
    ``background`` flag are checked against the truth.
``track``
    ``fusion-pf track FILE -o OUT --csv OUT.csv`` (through ``cli.main``); the
    CSV rows are identified by timestamp, the summary line and the loss
    warning are parsed.

and is put in one outcome class:

``ok``
    Every frame read (tracked), nothing reported.
``ok-with-report``
    Exit 0 (or 3) and every frame not read is reported (a count, or a
    truncation whose tail cannot be counted).
``refused-one-line``
    A ``fusion-pf: error:`` line / a ``FusionPFError`` (exit 2).
``traceback``
    Any other exception.
``hang``
    No answer within the time limit.
``frames-silently-missing``
    Silent frames: frames neither read (tracked) nor reported. For
    ``replay`` and ``track`` these are the frames the replay could read but
    that a person frame taken for background drops (``track``: read, not a
    background frame, and not in the CSV), plus the frames not read beyond the
    reported count (frames after a truncation whose tail cannot be counted
    excepted).

``--input mkv`` / ``--input avi`` fuzz a small video instead (30 frames of
64 x 48, FFmpeg's mpeg4 encoder through PyAV; the first six kinds) through
``import`` and ``track``: the frames imported / tracked plus the frames the
warning counts must be every frame of the video (``+``, an uncountable tail,
counts as reported).

Figures besides the classes: silent frames, frames whose ``index`` / CSV
``frame`` is not their index in the recording (misnumbered), background frames
tracked as person frames (after a warning that the background section cannot
be placed or is unknown), and whether the lost background frames printed by
``track`` match the truth.

Run from the repository root; choose the code under test with PYTHONPATH::

    PYTHONPATH=$PWD python benchmarks/fuzz_recordings.py --mutations 1200 --seed 1
    PYTHONPATH=/work/main python benchmarks/fuzz_recordings.py --mutations 1200 --seed 1   # before

The recording is written by the code under test (its own recorder). Results
go to stdout (counts per class and check) and ``--out`` (JSON with examples).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import multiprocessing as mp
import re
import sys
import tempfile
import time
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np

#: Mutation kinds, drawn uniformly.
KINDS = ("truncate", "flip", "zero", "remove", "duplicate", "junk", "remove-before-background", "remove-in-background")
#: Outcome classes, in report order.
CLASSES = ("ok", "ok-with-report", "refused-one-line", "traceback", "hang", "frames-silently-missing")


def make_recording(
    path: Path, frames: int = 40, size: str = "160x100", chunk_size: int = 200_000, background: int = 6
) -> dict:
    """Write a synthetic recording with the recorder under test; return its truth (:func:`truth_of`)."""
    from drivers import open_source
    from drivers.mcap_record import McapRecorder

    with open_source(f"synth:frames={frames},seed=3,size={size},background_frames={background}") as src:
        with McapRecorder(path, metadata=src.metadata(), chunk_size=chunk_size) as rec:
            for frame in src:
                rec.write(frame)
    return truth_of(path, background)


def truth_of(path: Path, background: int) -> dict:
    """``{"frames", "background", "times", "bg_lo", "first_chunk", "bg_hi"}`` of an undamaged recording.

    ``times`` are the colour log times in frame order; ``bg_lo`` is the end of
    the header record (where the metadata records start), ``first_chunk`` the
    first chunk's offset, ``bg_hi`` the end of the last chunk holding a
    background frame (byte offsets), read with the mcap library.
    """
    import struct

    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        times = sorted(m.log_time for _s, ch, m in reader.iter_messages() if ch.topic == "/camera/color")
        chunks = reader.get_summary().chunk_indexes
    data = path.read_bytes()
    last_bg = times[background - 1] if background else -1
    bg_chunks = [c for c in chunks if c.message_start_time <= last_bg]
    bg_hi = max((c.chunk_start_offset + c.chunk_length for c in bg_chunks), default=8 + 9)
    bg_lo = 8 + 9 + struct.unpack_from("<Q", data, 9)[0]
    first = min(c.chunk_start_offset for c in chunks)
    return {
        "frames": len(times),
        "background": background,
        "times": times,
        "bg_lo": bg_lo,
        "first_chunk": first,
        "bg_hi": bg_hi,
    }


def mutate(
    data: bytes, rng: np.random.Generator, truth: dict | None = None, kinds: tuple[str, ...] | None = None
) -> tuple[str, bytes]:
    """One random mutation of ``data`` of one of ``kinds`` (default :data:`KINDS`): ``(description, mutated bytes)``.

    The background-section kinds need ``truth`` (:func:`truth_of`); without it
    they are not drawn.
    """
    n = len(data)
    kinds = kinds or (KINDS if truth is not None and truth["background"] else KINDS[:6])
    kind = kinds[int(rng.integers(len(kinds)))]
    buf = bytearray(data)
    if kind in ("remove-before-background", "remove-in-background"):
        assert truth is not None
        lo, hi = truth["bg_lo"], truth["bg_hi"]
        first = truth["first_chunk"]
        if kind == "remove-before-background":  # starts before the first chunk, may reach into the background
            start = int(rng.integers(8, first))
            length = int(rng.integers(1, max(2, first - start + (hi - first) // 2)))
        else:
            start = int(rng.integers(lo, hi))
            length = int(rng.integers(1, max(2, hi - start + 1)))
        return f"{kind} {length} bytes at {start}", bytes(buf[:start] + buf[start + length :])
    if kind == "truncate":
        cut = int(rng.integers(1, n))
        return f"truncate at {cut}", bytes(buf[:cut])
    if kind == "flip":
        k = int(rng.integers(1, 9))
        where = rng.integers(0, n, k)
        for at in where:
            buf[int(at)] ^= 1 << int(rng.integers(8))
        return f"flip {k} bits at {sorted(int(a) for a in where)}", bytes(buf)
    if kind == "junk":
        k = int(rng.integers(1, 4096))
        return f"append {k} junk bytes", bytes(buf) + rng.integers(0, 256, k, dtype=np.uint8).tobytes()
    length = int(rng.integers(1, max(2, n // 8)))
    start = int(rng.integers(0, n - length))
    if kind == "zero":
        buf[start : start + length] = bytes(length)
        return f"zero {length} bytes at {start}", bytes(buf)
    if kind == "remove":
        return f"remove {length} bytes at {start}", bytes(buf[:start] + buf[start + length :])
    return f"duplicate {length} bytes at {start}", bytes(buf[: start + length] + buf[start:])


def _reported(stats: object) -> tuple[int, bool]:
    """``(frames reported lost, whether an uncountable loss such as a truncated tail is reported)``."""
    losses = getattr(stats, "losses", None)
    if losses is not None:  # this branch's SourceStats
        return sum(x.frames or 0 for x in losses), any(x.frames is None for x in losses)
    notes = getattr(stats, "notes", [])  # older SourceStats: dropped, and a truncation note
    return int(getattr(stats, "dropped", 0)), any("truncated" in note for note in notes)


def _skipped_counts(skipped: re.Match | None) -> tuple[int, bool]:
    """Frames the loss line counts, and whether it says an unknown number more were lost."""
    if skipped is None:
        return 0, False
    if not skipped.group(1).isdigit():
        return 0, True
    return int(skipped.group(1)), bool(skipped.group(2))


def _unaccounted(truth: dict, read: set[int], lost: int, unknown: bool) -> int:
    """Frames neither read nor within the reported count ``lost``; with an uncountable tail, frames after the last read one are covered."""
    missing = set(range(truth["frames"])) - read
    if unknown:
        last = max(read, default=-1)
        missing = {i for i in missing if i < last}
    return max(0, len(missing) - lost)


def check_replay(path: str, truth: dict) -> dict:
    """Replay every frame; check each frame's index and background flag; classify the outcome."""
    from drivers.mcap_replay import McapReplay
    from fusion_pf.errors import FusionPFError

    by_time = {t: i for i, t in enumerate(truth["times"])}
    k = truth["background"]
    read: set[int] = set()
    taken_for_background = misnumbered = background_tracked = 0
    try:
        with McapReplay(path) as replay:
            for frame in replay:
                i = by_time[frame.timestamp_ns]
                read.add(i)
                misnumbered += getattr(frame, "index", i) != i
                taken_for_background += frame.background and i >= k
                background_tracked += not frame.background and i < k
            lost, unknown = _reported(replay.stats)
            summary = getattr(replay.stats, "loss_summary", lambda: "")()
            warned = bool(getattr(replay.stats, "warnings", []))
    except FusionPFError as exc:
        text = str(exc)
        return {"class": "refused-one-line" if "\n" not in text else "traceback", "detail": text[:300]}
    except BaseException as exc:
        return {"class": "traceback", "detail": f"{type(exc).__name__}: {str(exc)[:300]}"}
    n = len(read)
    silent = taken_for_background + _unaccounted(truth, read, lost, unknown)
    detail = {
        "frames": n,
        "reported_lost": lost,
        "unknown": unknown,
        "silent": silent,
        "misnumbered": misnumbered,
        "background_tracked": background_tracked,
        "warned": warned,
        "summary": summary[:300],
    }
    if silent:
        return {"class": "frames-silently-missing", **detail}
    if n >= truth["frames"] and not lost and not unknown and not warned:
        return {"class": "ok", **detail}
    return {"class": "ok-with-report", **detail}


def check_info(path: str, truth: dict) -> dict:
    """``fusion-pf info --verify --json PATH`` through ``cli.main``; classify the outcome."""
    from fusion_pf import cli

    expected = truth["frames"]
    out, err = io.StringIO(), io.StringIO()
    try:
        with redirect_stdout(out), redirect_stderr(err):
            code = cli.main(["info", "--verify", "--json", path])
    except BaseException as exc:
        return {"class": "traceback", "detail": f"{type(exc).__name__}: {str(exc)[:300]}"}
    lines = [line for line in err.getvalue().splitlines() if line.strip()]
    if "Traceback" in err.getvalue():
        return {"class": "traceback", "detail": err.getvalue()[-300:]}
    if code == 2:
        ok = len([line for line in lines if line.startswith("fusion-pf: error:")]) == 1
        return {"class": "refused-one-line" if ok else "traceback", "detail": (lines or [""])[-1][:300]}
    if code not in (0, 3):
        return {"class": "traceback", "detail": f"exit {code}: {(lines or [''])[-1][:300]}"}
    try:
        doc = json.loads(out.getvalue())
        decoded, dropped = doc["verified"]["frames"], doc["verified"]["dropped"]
    except (ValueError, KeyError) as exc:
        return {"class": "traceback", "detail": f"unreadable --json output ({exc})"}
    detail = {"frames": decoded, "reported_lost": dropped, "silent": 0, "detail": (lines or [""])[0][:300]}
    if decoded >= expected and not lines:
        return {"class": "ok", **detail}
    unknown = any(x.get("frames") is None for x in doc["verified"].get("losses", []))
    if decoded + dropped >= expected or doc.get("truncated") or unknown:
        return {"class": "ok-with-report", **detail}
    return {"class": "frames-silently-missing", **{**detail, "silent": expected - decoded - dropped}}


#: ``tracked 34 frames (4 background, 2 background lost) of ...``
_TRACKED = re.compile(r"^tracked (\d+) frames \((\d+) background(?:, (\d+) background lost)?\)")
#: ``fusion-pf: warning: skipped 2 frames and an unknown number more: ...`` (``skipped an unknown number of
#: frames`` when that is all)
_SKIPPED = re.compile(r"^fusion-pf: warning: skipped (\d+|an unknown number of) frames?( and an unknown number more)?")


def _run_cli(argv: list[str]) -> tuple[dict | None, int, str, str, list[str]]:
    """``cli.main(argv)`` with its output captured: ``(outcome, exit, stdout, stderr, non-blank stderr lines)``.

    ``outcome`` is the class when that is already decided (a traceback, or a refusal
    in one line or more), else None.
    """
    from fusion_pf import cli

    out, err = io.StringIO(), io.StringIO()
    try:
        with redirect_stdout(out), redirect_stderr(err):
            code = cli.main(argv)
    except BaseException as exc:
        return {"class": "traceback", "detail": f"{type(exc).__name__}: {str(exc)[:300]}"}, -1, "", "", []
    text = err.getvalue()
    lines = [line for line in text.splitlines() if line.strip()]
    if "Traceback" in text:
        return {"class": "traceback", "detail": text[-300:]}, code, out.getvalue(), text, lines
    if code == 2:
        ok = len([line for line in lines if line.startswith("fusion-pf: error:")]) == 1
        outcome = {"class": "refused-one-line" if ok else "traceback", "detail": (lines or [""])[-1][:300]}
        return outcome, code, out.getvalue(), text, lines
    return None, code, out.getvalue(), text, lines


def check_track(path: str, truth: dict) -> dict:
    """``fusion-pf track PATH -o OUT --csv OUT.csv`` through ``cli.main``; count silent frames; classify."""
    from drivers.mcap_replay import McapReplay
    from fusion_pf.errors import FusionPFError

    by_time = {t: i for i, t in enumerate(truth["times"])}
    k = truth["background"]
    with tempfile.TemporaryDirectory() as tmp:
        table = Path(tmp) / "out.csv"
        failed, code, _out, text, lines = _run_cli(
            ["track", path, "-o", str(Path(tmp) / "out.mcap"), "--csv", str(table), "--no-progress"]
        )
        if failed is not None:
            return failed
        if code not in (0, 3):
            return {"class": "traceback", "detail": f"exit {code}: {(lines or [''])[-1][:300]}"}
        with open(table, newline="") as fh:
            rows = [(int(r["frame"]), by_time[int(r["timestamp_ns"])]) for r in csv.DictReader(fh)]
    head = next((m for m in map(_TRACKED.match, lines) if m), None)
    skipped = next((m for m in map(_SKIPPED.match, lines) if m), None)
    if head is None or int(head.group(1)) != len(rows):
        return {"class": "traceback", "detail": f"summary line missing or wrong: {lines[:3]}"}
    lost, unknown = _skipped_counts(skipped)
    try:  # which frames the file still holds (the recording's own times identify them)
        with McapReplay(path) as replay:
            read = {by_time[f.timestamp_ns] for f in replay}
    except FusionPFError:
        read = set()
    tracked = {i for _frame, i in rows}
    background_lost = len(set(range(k)) - read)
    silent = len({i for i in read if i >= k} - tracked) + _unaccounted(truth, read, lost, unknown)
    detail = {
        "frames": len(tracked),
        "background": int(head.group(2)),
        "reported_lost": lost,
        "unknown": unknown,
        "silent": silent,
        "misnumbered": sum(frame != i for frame, i in rows),
        "background_tracked": len({i for i in tracked if i < k}),
        "background_lost": background_lost,
        "background_lost_printed": int(head.group(3) or 0),
        "exit": code,
        "summary": (skipped.string if skipped else "")[:300],
    }
    if silent:
        return {"class": "frames-silently-missing", **detail}
    if code == 0 and len(tracked) == truth["frames"] - k and not lost:
        return {"class": "ok", **detail}
    return {"class": "ok-with-report", **detail}


def make_video(path: Path, frames: int = 30) -> dict:
    """Write a small mpeg4 video (``.mkv``, ``.avi`` by the suffix) with PyAV; return its truth."""
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=30)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        for i in range(frames):
            img = np.zeros((48, 64, 3), np.uint8)
            img[:, :, 0] = i * 8 % 256
            img[10:20, 2 * i % 64 : 2 * i % 64 + 8] = 255
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return {"frames": frames, "background": 0}


#: ``imported 29 frames`` / ``tracked 29 frames``
_DONE = re.compile(r"^(?:imported|tracked) (\d+) frames", re.M)


def _counted(argv: list[str], truth: dict) -> dict:
    """Run a command that reads a whole video; its frames done plus its frames reported must be all of them."""
    failed, code, out, text, lines = _run_cli(argv)
    if failed is not None:
        return failed
    done = _DONE.search(out + text)
    if code not in (0, 3) or done is None:
        return {"class": "traceback", "detail": f"exit {code}: {(lines or [''])[-1][:300]}"}
    skipped = next((m for m in map(_SKIPPED.match, lines) if m), None)
    lost, unknown = _skipped_counts(skipped)
    frames = int(done.group(1))
    silent = 0 if unknown else max(0, truth["frames"] - frames - lost)
    detail = {"frames": frames, "reported_lost": lost, "unknown": unknown, "silent": silent, "exit": code}
    detail["summary"] = (skipped.string if skipped else "")[:300]
    if silent:
        return {"class": "frames-silently-missing", **detail}
    return {"class": "ok" if code == 0 and frames >= truth["frames"] else "ok-with-report", **detail}


def check_import(path: str, truth: dict) -> dict:
    """``fusion-pf import VIDEO OUT.mcap``; classify."""
    with tempfile.TemporaryDirectory() as tmp:
        return _counted(["import", path, str(Path(tmp) / "out.mcap"), "--no-progress"], truth)


def check_track_video(path: str, truth: dict) -> dict:
    """``fusion-pf track VIDEO -o OUT.mcap``; classify."""
    with tempfile.TemporaryDirectory() as tmp:
        return _counted(["track", path, "-o", str(Path(tmp) / "out.mcap"), "--no-progress"], truth)


#: The checks, by name.
CHECKS = ("info", "replay", "track")
#: The checks of a video (``--input mkv|avi``).
VIDEO_CHECKS = ("import", "track-video")


def _worker(conn: "mp.connection.Connection") -> None:
    checks = {
        "info": check_info,
        "replay": check_replay,
        "track": check_track,
        "import": check_import,
        "track-video": check_track_video,
    }
    while True:
        task = conn.recv()
        if task is None:
            return
        name, path, truth = task
        conn.send(checks[name](path, truth))


class Pool:
    """Worker processes answering checks, each within ``timeout`` seconds (a hung worker is replaced)."""

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.ctx = mp.get_context("spawn")
        self._start()

    def _start(self) -> None:
        self.conn, child = self.ctx.Pipe()
        self.proc = self.ctx.Process(target=_worker, args=(child,), daemon=True)
        self.proc.start()

    def run(self, name: str, path: str, truth: dict) -> dict:
        """Outcome of check ``name`` on ``path`` (``{"class": "hang"}`` after the timeout)."""
        self.conn.send((name, path, truth))
        if self.conn.poll(self.timeout):
            try:
                return self.conn.recv()
            except EOFError:
                pass
            self.proc.join(5)
            self._start()
            return {"class": "traceback", "detail": f"worker died (exit {self.proc.exitcode})"}
        self.proc.kill()
        self.proc.join()
        self._start()
        return {"class": "hang", "detail": f"no answer in {self.timeout} s"}

    def close(self) -> None:
        """Stop the worker."""
        self.conn.send(None)
        self.proc.join(10)


def main(argv: list[str] | None = None) -> int:
    """Run the campaign and print the counts per outcome class."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mutations", type=int, default=1000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--background", type=int, default=6, help="leading background frames of the recording")
    p.add_argument("--track-every", type=int, default=1, metavar="N", help="run the track check on every N-th file")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds per check before it counts as a hang")
    p.add_argument("--out", type=Path, help="JSON file of every outcome")
    p.add_argument("--input", choices=("mcap", "mkv", "avi"), default="mcap", help="what to mutate")
    args = p.parse_args(argv)
    import drivers

    rng = np.random.default_rng(args.seed)
    pool = Pool(args.timeout)
    results = []
    started = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / f"base.{args.input}"
        if args.input == "mcap":
            checks = CHECKS
            truth = make_recording(base, frames=args.frames, background=args.background)
            about = (
                f"{truth['background']} background in bytes {truth['first_chunk']}-{truth['bg_hi']}, "
                f"metadata from byte {truth['bg_lo']}"
            )
        else:
            checks = VIDEO_CHECKS
            truth = make_video(base)
            about = "mpeg4 video"
        data = base.read_bytes()
        print(
            f"code under test: {Path(drivers.__file__).parent.parent}; {base.name} {len(data)} bytes, "
            f"{truth['frames']} frames ({about})",
            flush=True,
        )
        for k in range(args.mutations):
            what, mutated = mutate(data, rng, truth if args.input == "mcap" else None)
            path = Path(tmp) / f"m{k}{base.suffix}"
            path.write_bytes(mutated)
            row = {"mutation": what, "kind": what.split()[0]}
            for name in checks:
                if not name.startswith("track") or k % args.track_every == 0:
                    row[name] = pool.run(name, str(path), truth)
            results.append(row)
            path.unlink()
            if (k + 1) % 100 == 0:
                print(f"{k + 1} mutations, {time.monotonic() - started:.0f} s", file=sys.stderr, flush=True)
    pool.close()
    elapsed = time.monotonic() - started
    print(f"{args.mutations} mutations (seed {args.seed}) in {elapsed:.0f} s")
    print("mutations by kind: " + ", ".join(f"{k}={n}" for k, n in sorted(Counter(r["kind"] for r in results).items())))
    for name in checks:
        runs = [r[name] for r in results if name in r]
        counts = Counter(r["class"] for r in runs)
        print(f"{name:7s} files={len(runs)} " + "  ".join(f"{c}={counts.get(c, 0)}" for c in CLASSES))
    print("frames over the runs that read the file (not refused):")
    for name in checks:
        runs = [r[name] for r in results if name in r and "frames" in r[name]]
        figures = {
            "runs": len(runs),
            "read": sum(r["frames"] for r in runs),
            "reported_lost": sum(r.get("reported_lost", 0) for r in runs),
            "silent": sum(r.get("silent", 0) for r in runs),
            "misnumbered": sum(r.get("misnumbered", 0) for r in runs),
            "background_tracked": sum(r.get("background_tracked", 0) for r in runs),
        }
        if name == "track":
            figures["background_lost"] = sum(r["background_lost"] for r in runs)
            figures["background_lost_printed"] = sum(r["background_lost_printed"] for r in runs)
        print(f"{name:7s} " + " ".join(f"{k}={v}" for k, v in figures.items()))
    background_kinds = [r for r in results if r["kind"].endswith("background")]
    for name in checks if background_kinds else ():
        runs = [r[name] for r in background_kinds if name in r]
        counts = Counter(r["class"] for r in runs)
        silent = sum(r.get("silent", 0) for r in runs)
        print(
            f"{name:7s} background-section mutations: files={len(runs)} silent={silent} "
            + "  ".join(f"{c}={counts.get(c, 0)}" for c in CLASSES)
        )
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            json.dumps(
                {
                    "seed": args.seed,
                    "mutations": args.mutations,
                    "truth": {k: v for k, v in truth.items() if k != "times"},
                    "elapsed_s": elapsed,
                    "results": results,
                },
                indent=1,
            )
        )
    bad = sum(
        r[name]["class"] in ("traceback", "hang", "frames-silently-missing")
        for r in results
        for name in r
        if name in checks
    )
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
