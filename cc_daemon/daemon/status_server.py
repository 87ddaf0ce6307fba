"""The status socket inside the daemon: one small JSON document per connection.

A client connects and receives the status document (one line of JSON) and the
end of the stream; the server never parses what the client sends. That is the
whole protocol, so a hostile client has little to work with:
- garbage is never parsed: it is read and dropped (bounded in bytes and time)
  until the client closes, so the client still gets its document;
- a slow or stalled reader is cut off after `client_timeout_s` (a document fits
  in the socket's buffer, so in practice the write completes at once);
- beyond `max_clients` connections in progress, new ones are closed unanswered;
- the document is built at most every `CACHE_S`, so a flood of connections costs
  a copy each, not a snapshot each.
The socket is mode 0660: the daemon's user and group (the operators) only, never
world-writable.

It must never block the event loop, raise into the daemon, or change anything in
the daemon: it reads through `render`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import stat
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import structlog

from cc_daemon.config.statuspaths import daemon_socket_path

if TYPE_CHECKING:
    from cc_daemon.config import StatusSettings

_log = structlog.get_logger("cc_daemon.status")

SOCKET_MODE = 0o660
READ_LIMIT = 4096
MAX_DISCARD = 64 * 1024
MAX_LINGERING = 64
# asyncio accepts up to `backlog` connections per loop iteration, then runs all
# their handlers in the next: a small backlog keeps a flood's bursts short
# (R-P max during 1000 connections: ~50 ms at 128, ~33 ms at 16; benchmarks/status_flood.py).
BACKLOG = 16
CACHE_S = 0.2
RETRY_BIND_S = 30.0


class SocketBusy(OSError):
    """Another live process already answers on the socket's path."""


class StatusServer:
    def __init__(
        self,
        path: Path,
        render: Callable[[], dict[str, Any]],
        *,
        max_clients: int = 32,
        client_timeout_s: float = 2.0,
    ) -> None:
        self.path = path
        self._render = render
        self._max_clients = max_clients
        self._timeout_s = client_timeout_s
        self._active = 0
        self._lingering = 0
        self._cached: tuple[float, bytes] | None = None
        self._server: asyncio.Server | None = None
        self._inode: int | None = None
        # What happened to clients (the tests read them).
        self.served = 0
        self.refused = 0
        self.cut_off = 0

    async def start(self) -> None:
        """Bind the socket (replacing a stale one); SocketBusy if one is alive."""
        _clear_stale(self.path)
        self._server = await asyncio.start_unix_server(
            self._serve_one, path=str(self.path), limit=READ_LIMIT, backlog=BACKLOG
        )
        # Before any client can matter: bind() gave the socket the umask's mode.
        os.chmod(self.path, SOCKET_MODE)
        self._inode = self.path.stat().st_ino
        _log.info("status socket serving", path=str(self.path))

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None
        with contextlib.suppress(OSError):
            if self._inode is not None and self.path.stat().st_ino == self._inode:
                self.path.unlink()  # ours: a newer daemon's socket is left alone

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

    async def _serve_one(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._active >= self._max_clients:
            self.refused += 1
            writer.transport.abort()
            return
        self._active += 1
        try:
            writer.write(self._document())
            async with asyncio.timeout(self._timeout_s):
                await writer.drain()
            writer.write_eof()
            self.served += 1
        except (TimeoutError, OSError):
            self.cut_off += 1
            writer.transport.abort()
            return
        finally:
            self._active -= 1
        await self._linger(reader, writer)

    async def _linger(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """Wait (bounded) for the client to close before closing our end.

        A unix socket closed with unread input resets the connection, and the client
        loses the document it has not read yet; so what a client sent is read and
        dropped until it closes, for at most `client_timeout_s` and `MAX_DISCARD`
        bytes, and for at most `MAX_LINGERING` clients at once (each holds a file
        descriptor). A client that sends nothing is unaffected by the limits.
        """
        if self._lingering < MAX_LINGERING:
            self._lingering += 1
            try:
                async with asyncio.timeout(self._timeout_s):
                    discarded = 0
                    while discarded <= MAX_DISCARD and (chunk := await reader.read(READ_LIMIT)):
                        discarded += len(chunk)
            except (TimeoutError, OSError):
                pass
            finally:
                self._lingering -= 1
        writer.close()
        with contextlib.suppress(TimeoutError, OSError):
            async with asyncio.timeout(self._timeout_s):
                await writer.wait_closed()


def _clear_stale(path: Path) -> None:
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(mode):
        raise SocketBusy(f"{path} exists and is not a socket; not replacing it")
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        probe.settimeout(0.5)
        try:
            probe.connect(str(path))
        except OSError:
            path.unlink()  # left by a daemon that died: nobody answers
            return
    raise SocketBusy(f"another process answers on {path}; not replacing it")


async def serve_status(
    settings: StatusSettings, render: Callable[[], dict[str, Any]], journal: Path | None = None
) -> None:
    """The daemon's status duty: serve `render()`'s document until cancelled; retry a
    socket that cannot be bound. `journal` is `store.path` (`statuspaths`' rule)."""
    path = daemon_socket_path(settings, journal=journal) if settings.enabled else None
    if path is None:
        if settings.enabled:
            _log.warning("no status socket: every path the rule gives is too long")
        await asyncio.Future()  # nothing to serve, for the daemon's lifetime
        return
    runtime = os.environ.get("XDG_RUNTIME_DIR", "")
    if settings.path is None and runtime and path.parent == Path(runtime) / "cc-daemon":
        # $XDG_RUNTIME_DIR/cc-daemon: ours to make, private to the user. Never the
        # journal's directory: a socket must not make a path the journal found gone.
        with contextlib.suppress(OSError):
            path.parent.mkdir(mode=0o700, exist_ok=True)
    _log.info("status socket", path=str(path))
    server = StatusServer(
        path,
        render,
        max_clients=settings.max_clients,
        client_timeout_s=settings.client_timeout_s,
    )
    await serve_until_cancelled(server, "status")


class BoundServer(Protocol):
    path: Path

    async def start(self) -> None: ...

    async def close(self) -> None: ...


async def serve_until_cancelled(server: BoundServer, what: str) -> None:
    """Bind `server` and serve until cancelled, then close it. A socket that cannot be
    bound (another daemon's, a path not there yet) is said and retried every
    RETRY_BIND_S: never a crash of the duty that serves it."""
    try:
        while True:
            try:
                await server.start()
                break
            except OSError as exc:
                _log.error(
                    f"{what} socket unavailable; retrying",
                    path=str(server.path),
                    error=str(exc),
                    retry_s=RETRY_BIND_S,
                )
                await asyncio.sleep(RETRY_BIND_S)
        await asyncio.Future()  # serve until the daemon cancels us
    finally:
        await server.close()
