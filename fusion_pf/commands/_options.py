"""Option fields shared by several commands (sweep sizes, worker counts, image sizes)."""

from __future__ import annotations

from typing import Any

from fusion_pf.errors import InputError
from fusion_pf.experiments.paper import PAPER_RUNS
from fusion_pf.options import option

#: Upper bound of ``--workers`` (processes of a local Dask cluster).
MAX_WORKERS = 1024


def _counts(text: str) -> tuple[int, ...]:
    from fusion_pf.experiments import parse_counts

    return parse_counts(text)


def _check_counts(label: str, value: Any) -> tuple[int, ...]:
    text = value if isinstance(value, str) else ",".join(map(str, value))
    try:
        return _counts(text)
    except InputError as exc:
        raise InputError(f"{label}: {exc}") from None


def _show_counts(value: tuple[int, ...] | None) -> str:
    return "no sweep" if value is None else ",".join(map(str, value))


def counts_option(default: tuple[int, ...] | None, **spec: Any) -> Any:
    """A field of comma-separated particle counts (``"5,10,25"``), each >= 1, none repeated."""
    return option(
        default,
        parse=_counts,
        check=_check_counts,
        show=_show_counts,
        metavar="N1,N2,...",
        optional=default is None,
        **spec,
    )


def runs_option() -> Any:
    """The ``--runs`` field: runs (seeds) per particle count, the paper's by default."""
    return option(
        PAPER_RUNS, kind="int", lo=1, hi=100_000, metavar="R", help="runs (seeds) per particle count (paper 003 §4.5)"
    )


def workers_option(help: str) -> Any:
    """The ``--workers`` field: processes of the local Dask cluster (None: one per core)."""
    return option(
        None, kind="int", lo=1, hi=MAX_WORKERS, optional=True, metavar="W", show=lambda v: "one per core", help=help
    )


def scheduler_option(help: str) -> Any:
    """The ``--scheduler`` field: an existing Dask scheduler instead of a local cluster (None)."""
    return option(
        None, kind="str", optional=True, metavar="tcp://HOST:PORT", show=lambda v: "a local cluster", help=help
    )


def check_cluster(workers: int | None, scheduler: str | None) -> None:
    """Refuse ``--workers`` with ``--scheduler`` (the local cluster's size against an existing cluster)."""
    if scheduler is not None and workers is not None:
        raise InputError("--workers sets the local cluster's size; with --scheduler the cluster's own workers run")


def fps_option(show: str, help: str) -> Any:
    """An optional frame rate in (0, 1000] frames/s; None means ``show``."""
    return option(None, kind="float", lo=0.001, hi=1000.0, optional=True, metavar="F", show=lambda v: show, help=help)


def parse_size(text: str) -> tuple[int, int]:
    """``"640x400"`` -> ``(640, 400)``."""
    parts = text.lower().replace(" ", "").split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise InputError(f"expected WxH in pixels, e.g. 640x400, got {text!r}") from None
    return w, h


def size_check(lo: int, hi: int):
    """A ``check`` of a ``(width, height)`` field: two integers, each in ``[lo, hi]``."""

    def check(label: str, value: Any) -> tuple[int, int]:
        ok = (
            isinstance(value, (tuple, list))
            and len(value) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi for v in value)
        )
        if not ok:
            got = "x".join(map(str, value)) if isinstance(value, tuple) and len(value) == 2 else repr(value)
            raise InputError(f"{label} must be WxH with both in [{lo}, {hi}], e.g. 640x400, got {got}")
        return int(value[0]), int(value[1])

    return check


def show_size(value: tuple[int, int] | None) -> str:
    """``(640, 400)`` -> ``"640x400"``."""
    return "none" if value is None else f"{value[0]}x{value[1]}"
