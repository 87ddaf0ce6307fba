"""Binding and accepting on the daemon's unix sockets (status, control), within caps.

A connection is looked at before any asyncio object is made for it: the peer's
credentials (SO_PEERCRED), then its socket's `Admission`. One refused costs an
accept, a getsockopt, at most one small send and a close, and holds nothing, so
a flood of connections costs the event loop little. A process out of
descriptors (EMFILE) stops accepting for a second, said once a window by the
rate-limited log, instead of asyncio's traceback per attempt.

Binding: a stale socket left by a dead daemon is replaced, a live one never
(`SocketBusy`); the socket is mode 0660 before it listens; a socket whose
directory another user could write is never bound (`directory_problem`: the
private directory is made 0700 here, and one that is not ours is refused).

It must never block the event loop, raise into the daemon, or keep a refused
connection open.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import socket
import stat
from collections.abc import Awaitable, Callable, Mapping
from pathlib import Path
from typing import Protocol

import structlog

from cc_daemon.config.statuspaths import private_directory, shared_directory
from cc_daemon.daemon.admission import Admission, Ticket
from cc_daemon.ground.peercred import Peer, peer_credentials

_log = structlog.get_logger("cc_daemon.sockets")

SOCKET_MODE = 0o660
# Connections accepted per turn of the event loop, as asyncio's own servers do: a
# small batch keeps a flood's bursts short (R-P max during 1000 connections: ~50 ms
# at 128, ~33 ms at 16; benchmarks/status_flood.py). Also the listen backlog.
BACKLOG = 16
ACCEPT_PAUSE_S = 1.0
RETRY_BIND_S = 30.0
_OUT_OF_RESOURCES = {errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM}

# (the connection's streams, its peer, the place it holds) -> served. The place is
# given back and the connection closed when it returns (the place earlier if the
# handler says so: `Ticket.release`).
Handler = Callable[[asyncio.StreamReader, asyncio.StreamWriter, Peer, Ticket], Awaitable[None]]
# (the peer, why it is refused) -> what to send it before closing (b"": nothing)
Refusal = Callable[[Peer, str], bytes]


class SocketBusy(OSError):
    """Another live process already answers on the socket's path."""


def clear_stale(path: Path) -> None:
    """Remove a socket nobody answers on (a dead daemon's); SocketBusy otherwise."""
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


def directory_problem(path: Path, env: Mapping[str, str] | None = None) -> str | None:
    """Why the daemon must not bind `path`, or None. The private directory
    (`statuspaths.private_directory`) is made here, 0700, and must be ours and
    writable by us alone; any other must not be writable by another user."""
    directory = path.parent
    if directory == private_directory(env):
        with contextlib.suppress(FileExistsError):
            directory.mkdir(mode=0o700)
        try:
            info = directory.lstat()
        except OSError as exc:
            return f"{directory} cannot be made: {exc.strerror or exc}"
        if not stat.S_ISDIR(info.st_mode):
            return f"{directory} is not a directory"
        if info.st_uid != os.geteuid():
            return f"{directory} belongs to another user (uid {info.st_uid})"
        if info.st_mode & 0o022:
            return f"{directory} may be written by others (mode {stat.S_IMODE(info.st_mode):04o})"
        return None
    return shared_directory(path)


class Listener:
    """One bound unix socket: accepts within `admission`, hands each admitted
    connection to `handle` in its own task, and `refuse`s the others at once."""

    def __init__(
        self,
        path: Path,
        handle: Handler,
        admission: Admission,
        *,
        what: str,
        refuse: Refusal | None = None,
        limit: int = 4096,
    ) -> None:
        self.path = path
        self._handle = handle
        self._admission = admission
        self._refuse = refuse
        self._what = what
        self._limit = limit
        self._sock: socket.socket | None = None
        self._inode: int | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._paused: asyncio.TimerHandle | None = None
        self.refused = 0

    async def start(self) -> None:
        """Bind (replacing a stale socket) and listen; SocketBusy if one is alive."""
        clear_stale(self.path)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(str(self.path))
            # Before it listens: bind() gave the socket the umask's mode, and a
            # socket that does not listen refuses every connection meanwhile.
            os.chmod(self.path, SOCKET_MODE)
            self._inode = self.path.stat().st_ino
            sock.listen(BACKLOG)
            sock.setblocking(False)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        asyncio.get_running_loop().add_reader(sock.fileno(), self._accept)

    async def close(self) -> None:
        loop = asyncio.get_running_loop()
        if self._paused is not None:
            self._paused.cancel()
            self._paused = None
        if self._sock is not None:
            loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
        with contextlib.suppress(OSError):
            if self._inode is not None and self.path.stat().st_ino == self._inode:
                self.path.unlink()  # ours: a newer daemon's socket is left alone
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)

    def _accept(self) -> None:
        sock = self._sock
        assert sock is not None
        for _ in range(BACKLOG):
            try:
                conn, _ = sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if exc.errno in _OUT_OF_RESOURCES:
                    self._pause(exc)
                # ECONNABORTED and the like: that client is gone; the others wait.
                return
            try:
                self._admit(conn)
            except Exception:  # a client's trouble never reaches the event loop
                conn.close()
                _log.error(f"{self._what} socket: accepting failed", exc_info=True)

    def _admit(self, conn: socket.socket) -> None:
        try:
            peer = peer_credentials(conn)
        except OSError:
            conn.close()
            return
        ticket = self._admission.admit(peer.uid)
        if isinstance(ticket, str):
            self.refused += 1
            # uid and why only: the log's rate limit counts the repeats of a flood.
            _log.warning(f"{self._what} socket: connection refused", uid=peer.uid, why=ticket)
            answer = self._refuse(peer, ticket) if self._refuse is not None else b""
            if answer:
                with contextlib.suppress(OSError):
                    conn.send(answer, socket.MSG_DONTWAIT)
            conn.close()
            return
        conn.setblocking(False)
        task = asyncio.get_running_loop().create_task(self._serve(conn, peer, ticket))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _serve(self, conn: socket.socket, peer: Peer, ticket: Ticket) -> None:
        writer: asyncio.StreamWriter | None = None
        try:
            reader, writer = await asyncio.open_unix_connection(sock=conn, limit=self._limit)
            await self._handle(reader, writer, peer, ticket)
        except Exception as exc:  # a client's trouble never reaches the daemon
            _log.warning(
                f"{self._what} socket: a client failed", error=f"{type(exc).__name__}: {exc}"
            )
        finally:
            ticket.release()
            if writer is None:
                conn.close()
            elif writer.transport.get_write_buffer_size():
                writer.transport.abort()  # a reader that stalled: nothing more is owed
            else:
                writer.close()

    def _pause(self, exc: OSError) -> None:
        """Out of descriptors: stop accepting for a while (the clients wait in the
        backlog) rather than spin on a listening socket that is always ready."""
        sock = self._sock
        if sock is None or self._paused is not None:
            return
        _log.error(
            f"{self._what} socket: cannot accept, out of resources; pausing",
            error=exc.strerror,
            pause_s=ACCEPT_PAUSE_S,
        )
        loop = asyncio.get_running_loop()
        loop.remove_reader(sock.fileno())

        def resume() -> None:
            self._paused = None
            if self._sock is not None:
                loop.add_reader(self._sock.fileno(), self._accept)

        self._paused = loop.call_later(ACCEPT_PAUSE_S, resume)


class BoundServer(Protocol):
    @property
    def path(self) -> Path: ...

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
