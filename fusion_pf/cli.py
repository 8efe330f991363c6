"""The ``fusion-pf`` command line.

Each subcommand is a module in :mod:`fusion_pf.commands` defining ``NAME``,
``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``. Heavy imports happen
inside ``run`` so ``fusion-pf --help`` stays fast.

User errors (:class:`~fusion_pf.errors.FusionPFError`, a missing file) print one
line ``fusion-pf: error: ...`` and exit non-zero, without a traceback. Ctrl-C
exits 130 after the running command has finalised its outputs.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import __version__, commands
from .errors import FusionPFError


def _command_modules() -> list:
    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_"))
    return [importlib.import_module(f"{commands.__name__}.{name}") for name in names]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="fusion-pf",
        description=(
            "RGB-D palm tracker: a data-fusion particle filter over colour, depth and "
            "skeleton cues (Tasci & Celebi 2021). Pixels are colour-image pixels, depth "
            "is millimetres, times are integer nanoseconds."
        ),
    )
    parser.add_argument("--version", action="version", version=f"fusion-pf {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in _command_modules():
        p = sub.add_parser(
            module.NAME,
            help=module.HELP,
            description=getattr(module, "DESCRIPTION", module.HELP),
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        )
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``fusion-pf`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except FusionPFError as exc:
        print(f"fusion-pf: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except FileNotFoundError as exc:
        print(f"fusion-pf: error: no such file: {exc.filename}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"fusion-pf: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fusion-pf: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
