"""Hold Ctrl-C back while a unit of output is written, so files always end on a whole unit."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

_held: list[int] = []
_depth = 0


@contextmanager
def sigint_deferred() -> Iterator[None]:
    """Defer SIGINT (Ctrl-C) until the block ends, then raise KeyboardInterrupt.

    A Python-level handler is installed for the block, so the deferral holds
    whichever OS thread the signal is delivered to (OpenCV and tqdm start
    threads, so blocking the signal in the main thread is not enough). Nested
    blocks defer to the outermost one. Outside the main thread, or when SIGINT
    is not handled by Python, the block runs unprotected.
    """
    global _depth
    if threading.current_thread() is not threading.main_thread() or _depth:
        yield
        return
    previous = signal.getsignal(signal.SIGINT)
    if previous is None:
        yield
        return
    signal.signal(signal.SIGINT, lambda signum, _frame: _held.append(signum))
    _depth = 1
    try:
        yield
    finally:
        _depth = 0
        signal.signal(signal.SIGINT, previous)
    if _held:
        _held.clear()
        raise KeyboardInterrupt
