"""The annotation server's connection guard: caps per client and in all, a request deadline, descriptors.

waitress alone fails against a local flood (issue 24): its ``select()`` loop dies on a descriptor >= 1024; at
``connection_limit`` it stops accepting, so every operator waits for idle connections to time out; and its idle
timeout restarts on every byte, so a client trickling a byte every few seconds holds a slot for ever.
:class:`GuardedServer` is waitress's TCP server with

* a ``poll()`` loop (no descriptor bound);
* admission (:meth:`GuardedServer.handle_accept`): a client address keeps at most ``per_client`` connections and
  the server ``total``. A new connection beyond either *retires* the oldest idle connection (no request in
  service) of that address, or of the address holding the most, and is refused (closed) only when none is idle;
* a request deadline (:meth:`GuardedServer.maintenance`): a connection that has not handed in a complete request
  within ``channel_timeout`` seconds of opening or of its previous request is retired, whatever it trickles;
* out of descriptors on accept (EMFILE, ENFILE): it retires the oldest idle connection, or pauses accepting for
  :data:`ACCEPT_PAUSE_S` when none is idle, instead of spinning on a listener that stays readable.

Retiring shuts the socket down at once and lets waitress close it on the next loop pass, so the descriptor is
freed within a pass even when the client reads nothing, and it is never reused by an accept while the current
pass's poll results still name it (the listener is served before the connections in every pass).
"""

from __future__ import annotations

import errno
import logging
import resource
import socket
import time
from collections.abc import Iterable
from typing import Any

from waitress.adjustments import Adjustments
from waitress.channel import HTTPChannel
from waitress.server import TcpWSGIServer

from .options import ServeOptions

__all__ = ["ACCEPT_BATCH", "FD_RESERVE", "GuardedChannel", "GuardedServer", "create_server", "raise_descriptor_limit"]

#: Connections accepted per wake-up of the loop at most. Caps of at least twice this keep a new connection from
#: being retired before its request is read (the floor of ``ServeOptions``' two connection caps).
ACCEPT_BATCH = 16
#: Descriptors kept free beside the connections: listener, wake-up pipe, database, recording, retiring sockets.
FD_RESERVE = 64
#: Seconds the server stops accepting when out of descriptors with no idle connection to retire.
ACCEPT_PAUSE_S = 0.1
#: Seconds between two log lines counting the connections retired or refused to keep the caps.
REPORT_EVERY_S = 10.0

#: ``accept()`` errors meaning "out of descriptors or kernel memory" (not a bad peer).
_EXHAUSTED = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})

_log = logging.getLogger(__name__)


class GuardedChannel(HTTPChannel):
    """A waitress channel that knows its client address and when it last handed in a complete request."""

    def __init__(self, server: GuardedServer, sock: socket.socket, addr: Any, adj: Adjustments, map=None) -> None:
        self.client: str = addr[0]
        self.since = time.monotonic()  # opened, or last complete request (GuardedServer.add_task)
        super().__init__(server, sock, addr, adj, map=map)
        server.admitted(self)

    def del_channel(self, map=None) -> None:
        """Unregister from the loop and from the server's per-client count."""
        super().del_channel(map)
        self.server.forget(self)


class GuardedServer(TcpWSGIServer):
    """waitress's TCP server with connection caps, a request deadline and descriptor-shortage handling.

    Parameters
    ----------
    application : callable
        The WSGI application.
    adj : waitress.adjustments.Adjustments
        waitress's settings; ``listen[0]`` is bound and ``channel_timeout`` is the request deadline.
    per_client : int
        Connections kept per client address.
    total : int
        Connections kept in all.
    """

    channel_class = GuardedChannel

    def __init__(self, application: Any, adj: Adjustments, *, per_client: int, total: int) -> None:
        self.per_client = per_client
        self.total = total
        self.clients: dict[str, dict[GuardedChannel, None]] = {}  # live connections per address, oldest first
        self.live = 0
        self.retiring: set[GuardedChannel] = set()
        self.paused_until = 0.0
        self.counts = {"idle closed to admit new ones": 0, "refused": 0, "accepts out of descriptors": 0}
        self.next_report = 0.0
        super().__init__(application, adj=adj, sockinfo=adj.listen[0])

    def admitted(self, channel: GuardedChannel) -> None:
        """Count a new connection."""
        self.clients.setdefault(channel.client, {})[channel] = None
        self.live += 1

    def forget(self, channel: GuardedChannel) -> None:
        """Stop counting a connection (closed or retiring); idempotent."""
        self.retiring.discard(channel)
        mine = self.clients.get(channel.client, {})
        if channel in mine:
            del mine[channel]
            self.live -= 1
            if not mine:
                del self.clients[channel.client]

    def retire(self, channel: GuardedChannel) -> None:
        """Close an idle connection: shut it down now, let the loop close it on its next pass."""
        self.forget(channel)
        self.retiring.add(channel)
        channel.will_close = True
        try:
            channel.socket.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass  # already reset by the peer: the loop closes it all the same

    def add_task(self, task: Any) -> None:
        """A complete request was handed in: restart the connection's deadline, then queue it."""
        task.since = time.monotonic()
        super().add_task(task)

    def readable(self) -> bool:
        """Accept unless paused (waitress's check also runs :meth:`maintenance` every ``cleanup_interval``)."""
        accepting = bool(super().readable())
        return accepting and time.monotonic() >= self.paused_until

    def handle_accept(self) -> None:
        """Accept up to :data:`ACCEPT_BATCH` connections, each after making room for it under the caps."""
        for _ in range(ACCEPT_BATCH):
            try:
                pair = self.accept()
            except OSError as exc:
                self._accept_failed(exc)
                return
            if pair is None:
                return
            conn, addr = pair
            if self._make_room(addr[0]):
                try:
                    self.set_socket_options(conn)
                    self.channel_class(self, conn, addr, self.adj, map=self._map)
                    continue
                except OSError:
                    pass  # the peer is already gone
            else:
                self.counts["refused"] += 1
            conn.close()

    def maintenance(self, now: float) -> None:
        """Retire every idle connection past its request deadline (replaces waitress's per-byte idle timeout)."""
        cutoff = time.monotonic() - self.adj.channel_timeout
        late = [c for mine in self.clients.values() for c in mine if not c.requests and c.since < cutoff]
        for channel in late:
            self.retire(channel)
        self._report()

    def _make_room(self, client: str) -> bool:
        mine = self.clients.get(client, {})
        if len(mine) >= self.per_client:
            return self._retire_oldest_idle(mine)
        if self.live >= self.total:
            biggest = max(self.clients.values(), key=len)
            return self._retire_oldest_idle(biggest)
        return True

    def _retire_oldest_idle(self, channels: Iterable[GuardedChannel]) -> bool:
        idle = next((c for c in channels if not c.requests), None)
        if idle is None:
            return False
        self.retire(idle)
        self.counts["idle closed to admit new ones"] += 1
        return True

    def _accept_failed(self, exc: OSError) -> None:
        if exc.errno not in _EXHAUSTED:
            _log.warning("accept() failed: %s", exc)
            return
        self.counts["accepts out of descriptors"] += 1
        if self.retiring:
            return  # their descriptors are freed on this pass
        biggest = max(self.clients.values(), key=len, default={})
        if not self._retire_oldest_idle(biggest):
            self.paused_until = time.monotonic() + ACCEPT_PAUSE_S

    def _report(self) -> None:
        now = time.monotonic()
        if now < self.next_report or not any(self.counts.values()):
            return
        self.next_report = now + REPORT_EVERY_S
        counted = ", ".join(f"{n} {what}" for what, n in self.counts.items() if n)
        _log.warning(
            "connections: %s (caps: %d per client address, %d in all; %d open)",
            counted,
            self.per_client,
            self.total,
            self.live,
        )
        self.counts = dict.fromkeys(self.counts, 0)


def raise_descriptor_limit(connections: int) -> int:
    """Raise the soft descriptor limit toward the hard one so ``connections`` fit; return how many fit.

    Parameters
    ----------
    connections : int
        Connections wanted (:data:`FD_RESERVE` descriptors are kept beside them).

    Returns
    -------
    int
        ``connections``, or fewer when the hard limit (``ulimit -Hn``) does not allow them.
    """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = connections + FD_RESERVE
    if soft != resource.RLIM_INFINITY and soft < need:
        target = need if hard == resource.RLIM_INFINITY else min(need, hard)
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            soft = target
        except (ValueError, OSError):
            pass  # not allowed here: fit what the current limit allows
    if soft == resource.RLIM_INFINITY:
        return connections
    return max(1, min(connections, soft - FD_RESERVE))


def create_server(application: Any, opts: ServeOptions) -> GuardedServer:
    """A :class:`GuardedServer` bound to ``opts.host`` (its first address) and ``opts.port``, not yet running."""
    total = raise_descriptor_limit(opts.max_connections)
    if total < opts.max_connections:
        _log.warning(
            "the descriptor limit (ulimit -n) fits %d connections: serving at most %d, not %d",
            total,
            total,
            opts.max_connections,
        )
    adj = Adjustments(
        host=opts.host,
        port=opts.port,
        threads=opts.threads,
        max_request_body_size=1 << 20,
        ident="fusion-pf",
        asyncore_use_poll=True,
        channel_timeout=opts.idle_timeout,
        cleanup_interval=1,
        connection_limit=total + FD_RESERVE // 2,  # a backstop: the caps keep the loop's map below it
    )
    return GuardedServer(application, adj, per_client=min(opts.max_connections_per_client, total), total=total)
