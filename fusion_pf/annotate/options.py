"""The options of the annotation server (``fusion-pf annotate``), defined once.

:func:`~fusion_pf.annotate.server.serve` and
:class:`~fusion_pf.annotate.frames.FrameImages` take their defaults from
:class:`ServeOptions`; the command line makes its flags from it.
"""

from __future__ import annotations

from dataclasses import dataclass

from fusion_pf.options import option, validate

__all__ = ["COLOR_FORMATS", "ServeOptions"]

#: Image formats the colour frames can be sent to the browser in.
COLOR_FORMATS = ("jpeg", "png")


@dataclass(frozen=True)
class ServeOptions:
    """Where the annotator listens and how it serves the frames (validated on construction)."""

    host: str = option(
        "127.0.0.1",
        kind="str",
        help="interface to bind; anything but a loopback address exposes the tool to the network",
    )
    port: int = option(8765, kind="int", lo=0, hi=65535, help="TCP port (0 = pick a free one)")
    threads: int = option(8, kind="int", lo=1, hi=256, help="worker threads serving requests")
    image_format: str = option("jpeg", choices=COLOR_FORMATS, help="encoding of the colour frames sent to the browser")
    cache: int = option(256, kind="int", lo=1, hi=1_000_000, help="encoded images kept in memory (LRU)")
    # The connection caps' floor, 32, is twice connections.ACCEPT_BATCH: a new connection is read before
    # the newer ones from its address can make it the oldest idle one.
    max_connections: int = option(
        1000,
        kind="int",
        lo=32,
        hi=100_000,
        help="open connections kept at most; a new one beyond it closes the oldest idle connection of "
        "the client address holding the most",
    )
    max_connections_per_client: int = option(
        64,
        kind="int",
        lo=32,
        hi=100_000,
        help="open connections kept per client address; a new one beyond it closes that address's oldest "
        "idle connection (every local process shares 127.0.0.1)",
    )
    idle_timeout: int = option(
        30,
        kind="int",
        lo=1,
        hi=3600,
        unit="s",
        help="a connection that has not handed in a complete request for this long (since it opened or "
        "since its last request) is closed; bytes trickled in do not extend it",
    )

    def __post_init__(self) -> None:
        validate(self)
