"""Stop requests (Ctrl-C, SIGTERM, SIGHUP): hold them back while a unit of output is written.

:func:`sigint_deferred` keeps a stop request from splitting a unit of output
(a frame, a chunk, the summary of a file); :func:`stop_on_terminate` makes
SIGTERM and SIGHUP stop a command the way Ctrl-C does, so the command
finalises its outputs and prints its summary (``kill`` and a closed terminal
lose nothing more than Ctrl-C would).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

#: Signals a command may handle like Ctrl-C.
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))

_held: list[int] = []
_depth = 0


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised like Ctrl-C's KeyboardInterrupt.

    Attributes
    ----------
    signum : int
        The signal; the command line exits with ``128 + signum``.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(f"terminated by signal {signum}")
        self.signum = signum


def _raise_terminated(signum: int, _frame: Any) -> None:
    raise Terminated(signum)


@contextmanager
def stop_on_terminate() -> Iterator[None]:
    """Within the block, SIGTERM and SIGHUP raise :class:`Terminated` (a KeyboardInterrupt).

    Only in the main thread; the previous handlers are restored afterwards.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {}
    try:  # a stop arriving between two installations still restores the first
        for s in STOP_SIGNALS:
            if s != signal.SIGINT:
                previous[s] = signal.getsignal(s)
                signal.signal(s, _raise_terminated)
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)


@contextmanager
def sigint_deferred() -> Iterator[None]:
    """Defer Ctrl-C (and SIGTERM/SIGHUP when Python handles them) until the block ends, then raise.

    A Python-level handler is installed for the block, so the deferral holds
    whichever OS thread the signal is delivered to (OpenCV and tqdm start
    threads, so blocking the signal in the main thread is not enough). Nested
    blocks defer to the outermost one. Outside the main thread, or for a
    signal not handled by Python (default action, ignored), nothing changes.
    At the end of the block the first held signal's own handler runs: SIGINT
    raises KeyboardInterrupt, SIGTERM/SIGHUP under :func:`stop_on_terminate`
    raise :class:`Terminated`.
    """
    global _depth
    if threading.current_thread() is not threading.main_thread() or _depth:
        yield
        return
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    deferred = {s: h for s, h in previous.items() if callable(h)}
    if not deferred:
        yield
        return
    for s in deferred:
        signal.signal(s, lambda signum, _frame: _held.append(signum))
    _depth = 1
    try:
        yield
    finally:
        _depth = 0
        for s, handler in deferred.items():
            signal.signal(s, handler)
        held = list(_held)
        _held.clear()  # an exception leaving the block wins over a held stop request
    if held:
        signum = held[0]
        handler = deferred[signum]
        if handler is signal.default_int_handler:
            raise KeyboardInterrupt
        handler(signum, None)
