"""The status socket inside the daemon: one small JSON document per connection.

A client connects and receives the status document (one line of JSON) and the
end of the stream; the server never parses what the client sends. That is the
whole protocol, so a hostile client has little to work with:
- garbage is never parsed: it is read and dropped (bounded in bytes and time)
  until the client closes, so the client still gets its document;
- a slow or stalled reader is cut off after `client_timeout_s` (a document fits
  in the socket's buffer, so in practice the write completes at once);
- at most `max_clients` connections are written at once, `PER_PEER` of them by
  one user; more are closed unanswered before any work is done for them
  (`socket_listener`, `admission`: all within the descriptors the daemon keeps);
- the document is built at most every `CACHE_S`, so a flood of connections costs
  a copy each, not a snapshot each.
The socket is mode 0660: the daemon's user and group (the operators) only, never
world-writable, and never in a directory another user could write (`statuspaths`).

It must never block the event loop, raise into the daemon, or change anything in
the daemon: it reads through `render`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog

from cc_daemon.config.statuspaths import (
    DEFAULT_JOURNAL,
    daemon_socket_path,
    private_directory,
    shared_directory,
)
from cc_daemon.daemon.admission import SHARED, Admission, DescriptorBudget, Ticket
from cc_daemon.daemon.socket_listener import (
    Listener,
    SocketBusy,
    directory_problem,
    serve_until_cancelled,
)
from cc_daemon.ground.peercred import Peer

if TYPE_CHECKING:
    from cc_daemon.config import StatusSettings

__all__ = ["SocketBusy", "StatusServer", "serve_status"]

_log = structlog.get_logger("cc_daemon.status")

READ_LIMIT = 4096
MAX_DISCARD = 64 * 1024
MAX_LINGERING = 64
PER_PEER = 16  # connections written at once for one user (of max_clients)
LINGER_PER_PEER = 16  # of the MAX_LINGERING
CACHE_S = 0.2


class StatusServer:
    def __init__(
        self,
        path: Path,
        render: Callable[[], dict[str, Any]],
        *,
        max_clients: int = 32,
        client_timeout_s: float = 2.0,
        budget: DescriptorBudget = SHARED,
    ) -> None:
        self._render = render
        self._timeout_s = client_timeout_s
        self._writing = Admission(max_clients, min(PER_PEER, max_clients), budget)
        self._lingering = Admission(MAX_LINGERING, LINGER_PER_PEER, budget)
        self._listener = Listener(path, self._accepted, self._writing, what="status")
        self._cached: tuple[float, bytes] | None = None
        # What happened to clients (the tests read them).
        self.served = 0
        self.cut_off = 0

    @property
    def path(self) -> Path:
        return self._listener.path

    @property
    def refused(self) -> int:
        return self._listener.refused

    async def start(self) -> None:
        """Bind the socket (replacing a stale one); SocketBusy if one is alive."""
        await self._listener.start()
        _log.info("status socket serving", path=str(self.path))

    async def close(self) -> None:
        await self._listener.close()

    def _document(self) -> bytes:
        now = time.monotonic()
        if self._cached is not None and now - self._cached[0] < CACHE_S:
            return self._cached[1]
        try:
            document = self._render()
        except Exception as exc:
            _log.error("status document failed", exc_info=True)
            document = {"error": f"{type(exc).__name__}: {exc}"}
        data = (json.dumps(document, default=str, separators=(",", ":")) + "\n").encode()
        self._cached = (now, data)
        return data

    def _accepted(self, conn: socket.socket, peer: Peer, place: Ticket) -> None:
        """Answer at once: the document fits in the socket's buffer, so one send
        writes it and the connection is closed there and then, no task made. Only
        a document larger than the buffer, or a client that sent something (it
        must not lose its document to a reset), goes on in a task."""
        data = self._document()
        try:
            sent = conn.send(data)
        except BlockingIOError:
            sent = 0
        except OSError:  # the client left already
            place.release()
            conn.close()
            return
        if sent < len(data):
            self._listener.serve(conn, peer, place, partial(self._write_rest, data[sent:]))
            return
        self.served += 1
        place.release()
        with contextlib.suppress(OSError):
            conn.shutdown(socket.SHUT_WR)  # the end of the stream
        if _input_pending(conn):
            lingering = self._lingering.admit(peer.uid)
            if not isinstance(lingering, str):
                self._listener.serve(conn, peer, lingering, self._linger)
                return
        conn.close()

    async def _write_rest(
        self,
        rest: bytes,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        peer: Peer,
        place: Ticket,
    ) -> None:
        try:
            writer.write(rest)
            async with asyncio.timeout(self._timeout_s):
                await writer.drain()
            writer.write_eof()
            self.served += 1
        except (TimeoutError, OSError):
            self.cut_off += 1
            writer.transport.abort()
            return
        place.release()  # written: lingering has its own bound
        lingering = self._lingering.admit(peer.uid)
        if not isinstance(lingering, str):
            try:
                await self._linger(reader, writer, peer, lingering)
            finally:
                lingering.release()

    async def _linger(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        peer: Peer,
        place: Ticket,
    ) -> None:
        """Wait (bounded) for the client to close before closing our end.

        A unix socket closed with unread input resets the connection, and the client
        loses the document it has not read yet; so what a client sent is read and
        dropped until it closes, for at most `client_timeout_s` and `MAX_DISCARD`
        bytes, and for at most `MAX_LINGERING` clients at once, `LINGER_PER_PEER` of
        one user (each holds a file descriptor). A client that sends nothing is
        unaffected by the limits.
        """
        try:
            async with asyncio.timeout(self._timeout_s):
                discarded = 0
                while discarded <= MAX_DISCARD and (chunk := await reader.read(READ_LIMIT)):
                    discarded += len(chunk)
        except (TimeoutError, OSError):
            pass


def _input_pending(conn: socket.socket) -> bool:
    """Whether the client has sent something we have not read (not its close)."""
    try:
        return bool(conn.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT))
    except OSError:  # nothing yet (BlockingIOError), or gone
        return False


async def serve_status(
    settings: StatusSettings, render: Callable[[], dict[str, Any]], journal: Path | None = None
) -> None:
    """The daemon's status duty: serve `render()`'s document until cancelled; retry a
    socket that cannot be bound. `journal` is `store.path` (`statuspaths`' rule)."""
    path = daemon_socket_path(settings, journal=journal) if settings.enabled else None
    problem = directory_problem(path) if path is not None else None
    if path is None or problem is not None:
        if problem is not None:
            _log.error(f"no status or control socket: {problem}", path=str(path))
        elif settings.enabled:
            _log.warning("no status socket: every path the rule gives is too long")
        await asyncio.Future()  # nothing to serve, for the daemon's lifetime
        return
    _say_where(settings, journal, path)
    server = StatusServer(
        path,
        render,
        max_clients=settings.max_clients,
        client_timeout_s=settings.client_timeout_s,
    )
    await serve_until_cancelled(server, "status")


def _say_where(settings: StatusSettings, journal: Path | None, path: Path) -> None:
    """One line: the socket's path, and why it is not beside the journal if it is not."""
    journal = journal if journal is not None else DEFAULT_JOURNAL
    beside = Path(f"{Path(journal).absolute()}.status.sock")
    moved = settings.path is None and path.parent == private_directory()
    why = shared_directory(beside) if moved else None
    if why is None:
        _log.info("status socket", path=str(path))
        return
    _log.warning(
        f"status socket not beside the journal: {why}, so anyone could answer there;"
        f" serving in the private {path.parent} instead"
        f" (cc-daemon status --db {journal} finds it)",
        path=str(path),
    )
