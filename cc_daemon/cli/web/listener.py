"""The page's listening sockets and the connections it keeps (docs/web.md, "Limits").

This module owns which TCP connections the field page holds. It accepts them
itself rather than through asyncio's `create_server`, whose accept loop, out of
descriptors, logs a traceback for every try and retries each a second later,
however many piled up (the issue: 187,094 tracebacks in 40 s). Here:

- at most `Limits.connections` are open at once (fewer if the descriptor limit
  is low: `Limits.reserve_fds` stay free for the journal and the status socket),
  and at most `Limits.per_client` from one address; when the page is full, a
  newcomer from an address holding less than its share takes the place of a
  connection waiting for a request, the longest-waiting of the address holding
  the most (`Connections.admit`); a connection refused is closed at once, with a
  reset, before aiohttp sees it;
- a connection that sends no whole request head within `header_timeout_s` of
  opening, or `idle_timeout_s` of its last answer, is closed (slow headers,
  idle keep-alives);
- out of descriptors, accepting pauses (after closing the longest-waiting
  connection, if any), and the log gets one line a minute (the rate limiter of
  `ground.logsetup`), never one per try.

It never reads a request or writes an answer: aiohttp's `RequestHandler` does,
one per connection (`Guarded`, which also answers aiohttp's own 400s, for
requests it cannot parse, with the page's headers and without a traceback).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import resource
import socket
import struct
import time
from typing import Any

import structlog
from aiohttp import web
from aiohttp.web_protocol import RequestHandler
from aiohttp.web_request import BaseRequest

from cc_daemon.cli.web.policy import HEADERS, Limits

log = structlog.get_logger(__name__)

ACCEPT_PAUSE_S = 0.5  # out of descriptors with nothing to close: try again after this
# When the page is full and no address holds more than the newcomer's, a
# connection must have waited this long to be closed for it: newcomers cannot
# churn the page's connections faster than its cap a second.
MIN_WAIT_S = 1.0
SWEEP_S = 1.0  # how often the timeouts are looked at
# A long queue of connections waiting to be accepted, drained in bursts: when a
# flood fills it, the kernel drops a newcomer's SYN and the browser tries again
# only after 1, 3, 7 s... The kernel caps it at net.core.somaxconn.
BACKLOG = 1024
REFUSALS_AT_ONCE = 64  # refused (cheaply) between two turns of the loop's other work
_TRANSIENT = {errno.ECONNABORTED, errno.EPROTO, errno.EPERM, errno.EINTR, errno.EAGAIN}


def connection_cap(limits: Limits) -> int:
    """How many connections fit beside the reserve in this process's descriptor
    limit, raising its soft limit toward the hard one where that is allowed."""
    wanted = limits.connections + limits.reserve_fds
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < wanted:
        raised = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (raised, hard))
            soft = raised
    if soft == resource.RLIM_INFINITY:
        return limits.connections
    return max(0, min(limits.connections, soft - limits.reserve_fds))


def open_sockets(host: str, port: int) -> list[socket.socket]:
    """Bound, listening, non-blocking sockets for `host` (every address it names)
    and `port` (0: any free one, the same for all of them). OSError if not."""
    infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    made: list[socket.socket] = []
    seen: set[Any] = set()
    try:
        for family, kind, proto, _, address in infos:
            if address in seen:
                continue
            seen.add(address)
            sock = socket.socket(family, kind, proto)
            made.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            if port == 0 and len(made) > 1:  # one port for every address
                sock.bind((address[0], made[0].getsockname()[1], *address[2:]))
            else:
                sock.bind(address)
            sock.listen(BACKLOG)
            sock.setblocking(False)
    except BaseException:
        for sock in made:
            sock.close()
        raise
    return made


class Guarded(RequestHandler):
    """aiohttp's handler for one connection, which the `Connections` it belongs to
    can time out or close to make room."""

    def __init__(self, manager: web.Server, owner: Connections, client: str, **kw: Any) -> None:
        super().__init__(manager, **kw)
        self.owner = owner
        self.client = client
        self.since = time.monotonic()  # opened, or last answered
        self.answered = False
        self.busy = 0  # requests being answered

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        self.owner.add(self)

    def connection_lost(self, exc: BaseException | None) -> None:
        self.owner.remove(self)
        super().connection_lost(exc)

    def request_started(self) -> None:
        self.busy += 1

    def request_ended(self) -> None:
        self.busy -= 1
        self.answered = True
        self.since = time.monotonic()

    def waited(self, now: float) -> float | None:
        """Seconds spent waiting for a request (None: one is being answered)."""
        return None if self.busy else now - self.since

    def drop(self) -> None:
        if self.transport is not None:
            self.transport.abort()

    def handle_error(
        self,
        request: BaseRequest,
        status: int = 500,
        exc: BaseException | None = None,
        message: str | None = None,
    ) -> web.StreamResponse:
        """aiohttp's answer to what it could not parse (or, never here, a handler's
        failure): one JSON line with the page's headers, and one log line a minute
        whatever the client sent (nothing of it in the line: it may be anything)."""
        if status >= 500:
            log.error("the page failed a request", status=status, exc_info=exc)
        else:
            log.warning("a malformed request was refused", status=status)
        if request.writer.output_size > 0:
            raise ConnectionError("an answer was under way: the connection is closed")
        text = "the page failed" if status >= 500 else "a malformed HTTP request"
        response = web.json_response({"error": text}, status=status, headers=HEADERS)
        response.force_close()
        return response


class Connections:
    """The open connections: admitted, timed out and made room for, per `Limits`."""

    def __init__(self, limits: Limits, cap: int) -> None:
        self.limits = limits
        self.cap = cap
        self._open: set[Guarded] = set()
        self._per_client: dict[str, int] = {}
        self.refused = 0
        self.evicted = 0
        self.timed_out = 0

    def __len__(self) -> int:
        return len(self._open)

    def add(self, handler: Guarded) -> None:
        self._open.add(handler)
        self._per_client[handler.client] = self._per_client.get(handler.client, 0) + 1

    def remove(self, handler: Guarded) -> None:
        if handler not in self._open:
            return
        self._open.discard(handler)
        left = self._per_client[handler.client] - 1
        if left:
            self._per_client[handler.client] = left
        else:
            del self._per_client[handler.client]

    def admit(self, client: str) -> bool:
        """Whether a new connection from `client` may open (room is made if need be).

        When the page is full, an address holding its share (the cap over the
        addresses holding connections) or more is refused, cheaply, before any
        room is made: forty addresses holding a thousand connections cost their
        own re-tries, not the page's. One holding less takes the place of the
        longest-waiting connection of the address holding the most, or, where
        none holds more, of one that has waited MIN_WAIT_S at least."""
        mine = self._per_client.get(client, 0)
        if mine >= self.limits.per_client:
            self.refused += 1
            log.warning("a connection was refused: too many from one address")
            return False
        if len(self._open) < self.cap:
            return True
        share = self.cap // max(1, len(self._per_client) + (mine == 0))
        if mine < share and self.make_room(heavier_than=mine + 1):
            return True
        self.refused += 1
        log.warning("a connection was refused: the page is full")
        return False

    def make_room(self, heavier_than: int = 0) -> bool:
        """Close the connection that has waited longest for a request among those of
        the address holding the most (more than `heavier_than`; else, one that has
        waited MIN_WAIT_S at least); False if none may be closed."""
        now = time.monotonic()
        best: tuple[int, float, Guarded] | None = None
        for handler in self._open:
            waited = handler.waited(now)
            if waited is None:
                continue
            held = self._per_client[handler.client]
            if held <= heavier_than and waited < MIN_WAIT_S:
                continue
            rank = (held if held > heavier_than else 0, waited, handler)
            if best is None or rank[:2] > best[:2]:
                best = rank
        if best is None:
            return False
        self.evicted += 1
        log.warning("the page is full: the longest-waiting connection was closed")
        best[2].drop()
        self.remove(best[2])  # its descriptor is free now; aiohttp hears of it later
        return True

    def sweep(self) -> None:
        now = time.monotonic()
        for handler in list(self._open):
            waited = handler.waited(now)
            limit = self.limits.idle_timeout_s if handler.answered else self.limits.header_timeout_s
            if waited is not None and waited > limit:
                self.timed_out += 1
                handler.drop()
                self.remove(handler)


class Listener:
    """Accepts on `sockets` for `server` (aiohttp's), within `limits`, until closed."""

    def __init__(self, server: web.Server, sockets: list[socket.socket], limits: Limits) -> None:
        self._server = server
        self.sockets = sockets
        self.connections = Connections(limits, connection_cap(limits))
        self._tasks: list[asyncio.Task[None]] = []

    def start(self) -> None:
        for sock in self.sockets:
            self._tasks.append(asyncio.create_task(self._accept(sock), name="web-accept"))
        self._tasks.append(asyncio.create_task(self._sweep(), name="web-timeouts"))

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        for sock in self.sockets:
            sock.close()

    async def _sweep(self) -> None:
        while True:
            await asyncio.sleep(SWEEP_S)
            self.connections.sweep()

    def _handler(self, client: str) -> Guarded:
        limits = self.connections.limits
        return Guarded(
            self._server,
            self.connections,
            client,
            loop=asyncio.get_running_loop(),
            keepalive_timeout=limits.idle_timeout_s,
            access_log=None,
        )

    async def _accept(self, listener: socket.socket) -> None:
        loop = asyncio.get_running_loop()
        refused = 0
        while True:
            try:
                conn, address = await loop.sock_accept(listener)
            except OSError as exc:
                if exc.errno in _TRANSIENT:
                    continue
                # EMFILE, ENFILE, ENOBUFS, ENOMEM: make room, or wait for some.
                log.warning("cannot accept a connection", error=exc.strerror or str(exc))
                if not self.connections.make_room():
                    await asyncio.sleep(ACCEPT_PAUSE_S)
                continue
            client = str(address[0])
            if not self.connections.admit(client):
                _refuse(conn)
                refused += 1
                if refused % REFUSALS_AT_ONCE == 0:
                    await asyncio.sleep(0)  # a flood of refusals must not starve the loop
                continue
            try:
                await loop.connect_accepted_socket(functools.partial(self._handler, client), conn)
            except OSError:
                conn.close()


def _refuse(conn: socket.socket) -> None:
    """Close at once, with a reset: nothing is kept of the connection, not even TIME_WAIT."""
    with contextlib.suppress(OSError):
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    conn.close()
