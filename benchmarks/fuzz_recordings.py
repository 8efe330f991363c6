"""Fuzz campaign over damaged recordings: does every reader say what it lost?

A small synthetic recording is written, then mutated (seeded): truncation,
bit flips, zeroed blocks, removed byte ranges, duplicated byte ranges, junk
appended. Each mutant goes through two checks, each in a worker process with
a time limit:

``info``
    ``fusion-pf info --verify --json FILE`` (in the worker, through ``cli.main``).
``replay``
    ``McapReplay(FILE)``: iterate every frame.

and is put in one outcome class:

``ok``
    Every frame read, nothing reported.
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
    Fewer frames read than the recording holds, and the difference not reported.

Run from the repository root; choose the code under test with PYTHONPATH::

    PYTHONPATH=$PWD python benchmarks/fuzz_recordings.py --mutations 1200 --seed 1
    PYTHONPATH=/work/main python benchmarks/fuzz_recordings.py --mutations 1200 --seed 1   # before

The recording is written by the code under test (its own recorder). Results
go to stdout (counts per class and check) and ``--out`` (JSON with examples).
"""

from __future__ import annotations

import argparse
import io
import json
import multiprocessing as mp
import sys
import tempfile
import time
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np

#: Mutation kinds, drawn uniformly.
KINDS = ("truncate", "flip", "zero", "remove", "duplicate", "junk")
#: Outcome classes, in report order.
CLASSES = ("ok", "ok-with-report", "refused-one-line", "traceback", "hang", "frames-silently-missing")


def make_recording(path: Path, frames: int = 40, size: str = "160x100", chunk_size: int = 200_000) -> int:
    """Write a synthetic recording with the recorder under test; return its frame count."""
    from drivers import open_source
    from drivers.mcap_record import McapRecorder

    with open_source(f"synth:frames={frames},seed=3,size={size},background_frames=2") as src:
        with McapRecorder(path, metadata=src.metadata(), chunk_size=chunk_size) as rec:
            for frame in src:
                rec.write(frame)
    return frames


def mutate(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One random mutation of ``data``: ``(description, mutated bytes)``."""
    n = len(data)
    kind = KINDS[int(rng.integers(len(KINDS)))]
    buf = bytearray(data)
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


def check_replay(path: str, expected: int) -> dict:
    """Replay every frame; classify the outcome."""
    from drivers.mcap_replay import McapReplay
    from fusion_pf.errors import FusionPFError

    try:
        with McapReplay(path) as replay:
            n = sum(1 for _ in replay)
            lost, unknown = _reported(replay.stats)
            summary = getattr(replay.stats, "loss_summary", lambda: "")()
    except FusionPFError as exc:
        text = str(exc)
        return {"class": "refused-one-line" if "\n" not in text else "traceback", "detail": text[:300]}
    except BaseException as exc:
        return {"class": "traceback", "detail": f"{type(exc).__name__}: {str(exc)[:300]}"}
    detail = {"frames": n, "reported_lost": lost, "unknown": unknown, "summary": summary[:300]}
    if n >= expected and not lost and not unknown:
        return {"class": "ok", **detail}
    if n + lost >= expected or unknown:
        return {"class": "ok-with-report", **detail}
    return {"class": "frames-silently-missing", **detail}


def check_info(path: str, expected: int) -> dict:
    """``fusion-pf info --verify --json PATH`` through ``cli.main``; classify the outcome."""
    from fusion_pf import cli

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
    detail = {"frames": decoded, "reported_lost": dropped, "detail": (lines or [""])[0][:300]}
    if decoded >= expected and not lines:
        return {"class": "ok", **detail}
    unknown = any(x.get("frames") is None for x in doc["verified"].get("losses", []))
    if decoded + dropped >= expected or doc.get("truncated") or unknown:
        return {"class": "ok-with-report", **detail}
    return {"class": "frames-silently-missing", **detail}


def _worker(conn: "mp.connection.Connection") -> None:
    checks = {"info": check_info, "replay": check_replay}
    while True:
        task = conn.recv()
        if task is None:
            return
        name, path, expected = task
        conn.send(checks[name](path, expected))


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

    def run(self, name: str, path: str, expected: int) -> dict:
        """Outcome of check ``name`` on ``path`` (``{"class": "hang"}`` after the timeout)."""
        self.conn.send((name, path, expected))
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
    p.add_argument("--timeout", type=float, default=60.0, help="seconds per check before it counts as a hang")
    p.add_argument("--out", type=Path, help="JSON file of every outcome")
    args = p.parse_args(argv)
    import drivers

    rng = np.random.default_rng(args.seed)
    pool = Pool(args.timeout)
    results = []
    started = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "base.mcap"
        expected = make_recording(base, frames=args.frames)
        data = base.read_bytes()
        print(
            f"code under test: {Path(drivers.__file__).parent.parent}; recording {len(data)} bytes, {expected} frames",
            flush=True,
        )
        for k in range(args.mutations):
            what, mutated = mutate(data, rng)
            path = Path(tmp) / f"m{k}.mcap"
            path.write_bytes(mutated)
            row = {"mutation": what, "kind": what.split()[0]}
            for name in ("info", "replay"):
                row[name] = pool.run(name, str(path), expected)
            results.append(row)
            path.unlink()
            if (k + 1) % 100 == 0:
                print(f"{k + 1} mutations, {time.monotonic() - started:.0f} s", file=sys.stderr, flush=True)
    pool.close()
    elapsed = time.monotonic() - started
    print(f"{args.mutations} mutations (seed {args.seed}) in {elapsed:.0f} s")
    for name in ("info", "replay"):
        counts = Counter(r[name]["class"] for r in results)
        print(f"{name:7s} " + "  ".join(f"{c}={counts.get(c, 0)}" for c in CLASSES))
    print(
        "frames over the runs that read the file (not refused): read / reported lost / unaccounted "
        "(neither read nor counted; includes truncated tails)"
    )
    for name in ("info", "replay"):
        runs = [r[name] for r in results if "frames" in r[name]]
        read = sum(r["frames"] for r in runs)
        lost = sum(r.get("reported_lost", 0) for r in runs)
        gone = sum(max(0, expected - r["frames"] - r.get("reported_lost", 0)) for r in runs)
        print(f"{name:7s} runs={len(runs)} read={read} reported_lost={lost} unaccounted={gone}")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            json.dumps(
                {
                    "seed": args.seed,
                    "mutations": args.mutations,
                    "expected": expected,
                    "elapsed_s": elapsed,
                    "results": results,
                },
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
