"""A study of small recordings: sequential ``fusion-pf track`` calls against ``--out-dir`` on a local Dask cluster.

Makes ``--recordings`` synthetic recordings (``--frames`` each, 320x200), then
times: every recording tracked by its own ``fusion-pf track`` call, one after
the other (how a study is tracked without ``--out-dir``); the study in one
process (``--workers 1``); the study on a local cluster of ``--workers``
processes. Checks that every study CSV is byte-identical to the CSV of the
call alone and prints the wall times and their ratios.

    python benchmarks/study.py --recordings 20 --frames 60 --workers 2
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

CLI = (sys.executable, "-m", "fusion_pf")


def _run(*args: object) -> float:
    t0 = time.perf_counter()
    r = subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"fusion-pf {' '.join(map(str, args))} failed: {r.stderr.strip().splitlines()[-1:]}")
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--recordings", type=int, default=20)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("out/bench_study"))
    a = p.parse_args()
    shutil.rmtree(a.out, ignore_errors=True)
    recs = a.out / "recs"
    recs.mkdir(parents=True)
    for s in range(a.recordings):
        _run(
            "synth", recs / f"rec{s:03d}.mcap", "--frames", a.frames, "--seed", s, "--size", "320x200", "--no-progress"
        )
    alone = a.out / "alone"
    alone.mkdir()
    t_alone = sum(
        _run("track", rec, "-o", alone / f"{rec.stem}.mcap", "--csv", alone / f"{rec.stem}.csv", "--no-progress")
        for rec in sorted(recs.glob("*.mcap"))
    )
    t_one = _run("track", recs, "--out-dir", a.out / "one", "--workers", 1, "--no-progress")
    t_dask = _run("track", recs, "--out-dir", a.out / "dask", "--workers", a.workers, "--no-progress")
    same = all(
        (a.out / d / f"{rec.stem}.csv").read_bytes() == (alone / f"{rec.stem}.csv").read_bytes()
        for rec in recs.glob("*.mcap")
        for d in ("one", "dask")
    )
    print(f"{a.recordings} recordings x {a.frames} frames (320x200):")
    print(f"  {a.recordings} sequential 'fusion-pf track' calls: {t_alone:6.1f} s")
    print(f"  study, --workers 1 (one process):   {t_one:6.1f} s  ({t_one / t_alone:.2f} x sequential calls)")
    print(
        f"  study, --workers {a.workers} (local Dask):   {t_dask:6.1f} s  ({t_dask / t_alone:.2f} x sequential calls, "
        f"{t_dask / t_one:.2f} x --workers 1)"
    )
    print(f"  every study CSV byte-identical to its call alone: {same}")


if __name__ == "__main__":
    main()
