"""``fusion-pf bench``: time the particle filter, the reference libraries, the pipeline and replay."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "bench"
HELP = "benchmark the PF step, Stone Soup / particles / filterpy, the pipeline and replay"
DESCRIPTION = (
    "Measure the particle-filter step (predict + 3-source likelihood + normalise + ESS + residual "
    "resampling + estimate) for N = 1e2..1e6 against Stone Soup, nchopin particles and filterpy "
    "(same model and N), the likelihoods' robustness to a lying source, the per-stage latency of "
    "the tracking pipeline at 640x400 and 1280x800 with and without ROI, replay frames/s and peak "
    "memory. Writes OUT/bench.json and OUT/bench.md and prints the Markdown. Times are medians of "
    "repeats; other processes on the machine make them noisy (the load average is recorded)."
)

SECTIONS = ("pf", "stonesoup", "resampling", "robustness", "pipeline", "replay")


def _sizes(text: str) -> list[int]:
    try:
        sizes = [int(float(s)) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated particle counts, e.g. 1e2,1e4, got {text!r}"
        ) from None
    if not sizes or min(sizes) < 1 or max(sizes) > 10_000_000:
        raise argparse.ArgumentTypeError(f"particle counts must be in 1..1e7, got {text!r}")
    return sizes


def _sections(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in names if s not in SECTIONS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"sections must be among {','.join(SECTIONS)}, got {text!r}")
    return names


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf bench``."""
    p.add_argument("--quick", action="store_true", help="fewer repeats, smaller recordings (< 5 min)")
    p.add_argument("--out", type=Path, default=Path("bench-out"), metavar="DIR",
                   help="directory for bench.json and bench.md")
    p.add_argument("--sizes", type=_sizes, default="1e2,1e3,1e4,1e5,1e6", metavar="N,N,...",
                   help="particle counts of the PF-step and resampling sections")
    p.add_argument("--sections", type=_sections, default=",".join(SECTIONS), metavar="NAME,...",
                   help=f"which sections to run, among {','.join(SECTIONS)}")
    p.add_argument("--sample", type=Path, default=Path("recordings/sample.mcap"), metavar="FILE.mcap",
                   help="recording replayed end to end if it exists (else only synthetic ones)")


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and print the Markdown report."""
    import importlib.util
    import sys

    from fusion_pf.bench import run_bench, to_markdown
    from fusion_pf.errors import FusionPFError

    needed = {"stonesoup": ["stonesoup"], "resampling": ["particles", "filterpy"]}
    missing = [m for section in args.sections for m in needed.get(section, []) if importlib.util.find_spec(m) is None]
    if missing:
        raise FusionPFError(
            f"the reference libraries {', '.join(missing)} are not installed; install them with "
            "pip install 'fusion-pf[bench]', or choose --sections without stonesoup/resampling"
        )

    result = run_bench(
        args.out,
        quick=args.quick,
        sizes=args.sizes,
        sections=args.sections,
        sample=args.sample,
        progress=lambda line: print(f"bench: {line}", file=sys.stderr, flush=True),
    )
    print(to_markdown(result))
    print(f"wrote {args.out / 'bench.json'} and {args.out / 'bench.md'}", file=sys.stderr)
    return 0
