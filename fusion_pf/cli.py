"""The ``fusion-pf`` command line.

Each subcommand is a module in :mod:`fusion_pf.commands` defining ``NAME``,
``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``. Heavy imports happen
inside ``run`` so ``fusion-pf --help`` stays fast.

User errors (:class:`~fusion_pf.errors.FusionPFError`, a missing file) print one
line ``fusion-pf: error: ...`` and exit non-zero, without a traceback. Ctrl-C
exits 130 after the running command has finalised its outputs, SIGTERM 143 and
SIGHUP 129 likewise (see :mod:`fusion_pf.signals`), at any moment of the run. A
closed pipe (``fusion-pf info x.mcap | head``) ends the command quietly with
141, the status of a process killed by SIGPIPE.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from . import __version__, commands
from .errors import FusionPFError
from .text import printable


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
    """Entry point of the ``fusion-pf`` console script; returns the exit status.

    SIGTERM and SIGHUP stop every command like Ctrl-C from the first statement
    on, before the commands are imported: the running command finalises its
    outputs and the process exits 143 / 129 with one line, whichever statement
    the stop request arrives at.
    """
    from .signals import stop_on_terminate

    try:
        with stop_on_terminate():
            return _main(argv)
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", 2)
        try:
            print(
                "fusion-pf: interrupted" if signum == 2 else f"fusion-pf: terminated by signal {signum}",
                file=sys.stderr,
            )
        except KeyboardInterrupt:  # a second Ctrl-C while the first is reported: the process is ending anyway
            pass
        return 128 + signum


def _main(argv: list[str] | None) -> int:
    from .signals import sigint_deferred

    try:
        with sigint_deferred():  # a Ctrl-C while the commands import (numpy turns it into ImportError) waits
            args = build_parser().parse_args(argv)
        return int(args._run(args) or 0)
    except BrokenPipeError:
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 141
    except FusionPFError as exc:
        print(f"fusion-pf: error: {printable(exc)}", file=sys.stderr)
        return exc.exit_code
    except FileNotFoundError as exc:
        print(f"fusion-pf: error: no such file: {printable(exc.filename)}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(
            f"fusion-pf: error: {printable(exc.strerror or exc)}: {printable(exc.filename or '')}".rstrip(": "),
            file=sys.stderr,
        )
        return 2


if __name__ == "__main__":
    sys.exit(main())
