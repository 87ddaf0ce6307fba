"""Binding and accepting on the daemon's unix sockets (status, control), within caps.

A connection is looked at before any asyncio object is made for it: the peer's
credentials (SO_PEERCRED), then its socket's `Admission`. One refused costs an
accept, a getsockopt, at most one small send and a close, and holds nothing, so
a flood of connections costs the event loop little; refusals are logged once a
minute with their count (`Refusals`). One admitted is handed to its server at
once (the status server answers it there and then); a server that needs more
time goes on in a task (`Listener.serve`). A process out of descriptors
(EMFILE) stops accepting for a second, said by the rate-limited log, instead of
asyncio's traceback per attempt.

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
import time
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
# By default at most this many connections a second are accepted on one socket:
# above it the listener stops reading and the clients queue in the kernel (a
# client that connects and closes in a loop is slowed down to it), so what a
# socket costs the event loop has a ceiling however fast anyone connects
# (benchmarks/socket_attacks.py). Far above any real use of the status socket:
# the field page asks twice a second, `cc-daemon status --watch` at most ten times.
ACCEPTS_PER_S = 1000.0
ACCEPT_PAUSE_S = 1.0
RETRY_BIND_S = 30.0
REFUSALS_WINDOW_S = 60.0
_OUT_OF_RESOURCES = {errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM}

# (an admitted connection, non-blocking, its peer, the place it holds) -> None: at
# once, on the event loop. It closes the connection and gives the place back
# (`Ticket.release`), or hands both to `Listener.serve`.
Accepted = Callable[[socket.socket, Peer, Ticket], None]
# (the connection's streams, its peer, the place it holds) -> served, in a task. The
# place is given back and the connection closed when it returns (the place earlier
# if the handler says so).
Handler = Callable[[asyncio.StreamReader, asyncio.StreamWriter, Peer, Ticket], Awaitable[None]]
# (the peer, why it is refused) -> what to send it before closing (b"": nothing)
Refusal = Callable[[Peer, str], bytes]
# (a connection, its peer) -> None if it may be admitted, else (why, what to send it)
Vet = Callable[[socket.socket, Peer], tuple[str, bytes] | None]


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


class Refusals:
    """Connections a socket refused, said in the log at once, then once a window
    (`REFUSALS_WINDOW_S`) with their count: a flood is a line a minute, not a line
    a connection, and costs a counter, not a log call."""

    def __init__(self, what: str, clock: Callable[[], float] = time.monotonic) -> None:
        self._what = what
        self._clock = clock
        self._since: float | None = None
        self._counts: dict[tuple[int, str], int] = {}
        self.total = 0

    def add(self, uid: int, why: str) -> None:
        self.total += 1
        now = self._clock()
        if self._since is None or (not self._counts and now - self._since >= REFUSALS_WINDOW_S):
            self._since = now
            _log.warning(f"{self._what} socket: connection refused", uid=uid, why=why)
            return
        self._counts[(uid, why)] = self._counts.get((uid, why), 0) + 1
        if now - self._since >= REFUSALS_WINDOW_S:
            self.flush()

    def flush(self) -> None:
        """Say the counts held (at a window's end, and when the socket closes)."""
        now = self._clock()
        for (uid, why), count in self._counts.items():
            _log.warning(
                f"{self._what} socket: connections refused",
                uid=uid,
                why=why,
                count=count,
                in_s=round(now - (self._since or now)),
            )
        self._counts.clear()
        self._since = now


class Listener:
    """One bound unix socket: turns away at once the connections `vet` refuses and
    those over `admission` (sending them what `refuse` says), and hands each
    admitted one to `accepted` at once."""

    def __init__(
        self,
        path: Path,
        accepted: Accepted,
        admission: Admission,
        *,
        what: str,
        refuse: Refusal | None = None,
        vet: Vet | None = None,
        accepts_per_s: float = ACCEPTS_PER_S,
    ) -> None:
        self.path = path
        self._rate = accepts_per_s
        self._vet = vet
        self._accepted = accepted
        self._admission = admission
        self._refuse = refuse
        self._what = what
        self._sock: socket.socket | None = None
        self._inode: int | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._paused: asyncio.TimerHandle | None = None
        self._tokens = float(BACKLOG)
        self._filled_at = time.monotonic()
        self.refusals = Refusals(what)

    @property
    def refused(self) -> int:
        return self.refusals.total

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
        self.refusals.flush()
        tasks = list(self._tasks)
        for task in tasks:
            task.cancel()
        if tasks:
            await asyncio.wait(tasks)

    def serve(
        self, conn: socket.socket, peer: Peer, place: Ticket, handle: Handler, limit: int = 4096
    ) -> None:
        """Go on with an admitted connection in a task of its own, with streams; the
        place is given back and the connection closed when `handle` returns."""
        task = asyncio.get_running_loop().create_task(self._serve(conn, peer, place, handle, limit))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _accept(self) -> None:
        sock = self._sock
        assert sock is not None
        now = time.monotonic()
        self._tokens = min(BACKLOG * 4.0, self._tokens + (now - self._filled_at) * self._rate)
        self._filled_at = now
        if self._tokens < 1.0:
            self._pause_for((min(BACKLOG, self._rate) - self._tokens) / self._rate)
            return
        for _ in range(min(BACKLOG, int(self._tokens))):
            try:
                conn, _ = sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if exc.errno in _OUT_OF_RESOURCES:
                    self._pause(exc)
                # ECONNABORTED and the like: that client is gone; the others wait.
                return
            self._tokens -= 1.0
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
        vetted = self._vet(conn, peer) if self._vet is not None else None
        if vetted is not None:
            self._turn_away(conn, peer, *vetted)
            return
        place = self._admission.admit(peer.uid)
        if isinstance(place, str):
            answer = self._refuse(peer, place) if self._refuse is not None else b""
            self._turn_away(conn, peer, place, answer)
            return
        conn.setblocking(False)
        self._accepted(conn, peer, place)

    def _turn_away(self, conn: socket.socket, peer: Peer, why: str, answer: bytes) -> None:
        self.refusals.add(peer.uid, why)
        if answer:
            with contextlib.suppress(OSError):
                conn.send(answer, socket.MSG_DONTWAIT)
        conn.close()

    async def _serve(
        self, conn: socket.socket, peer: Peer, place: Ticket, handle: Handler, limit: int
    ) -> None:
        writer: asyncio.StreamWriter | None = None
        try:
            reader, writer = await asyncio.open_unix_connection(sock=conn, limit=limit)
            await handle(reader, writer, peer, place)
        except Exception as exc:  # a client's trouble never reaches the daemon
            _log.warning(
                f"{self._what} socket: a client failed", error=f"{type(exc).__name__}: {exc}"
            )
        finally:
            place.release()
            if writer is None:
                conn.close()
            elif writer.transport.get_write_buffer_size():
                writer.transport.abort()  # a reader that stalled: nothing more is owed
            else:
                writer.close()

    def _pause(self, exc: OSError) -> None:
        """Out of descriptors: stop accepting for a while (the clients wait in the
        backlog) rather than spin on a listening socket that is always ready."""
        if self._sock is None or self._paused is not None:
            return
        _log.error(
            f"{self._what} socket: cannot accept, out of resources; pausing",
            error=exc.strerror,
            pause_s=ACCEPT_PAUSE_S,
        )
        self._pause_for(ACCEPT_PAUSE_S)

    def _pause_for(self, seconds: float) -> None:
        """Stop reading the listening socket for `seconds` (no timer runs otherwise)."""
        sock = self._sock
        if sock is None or self._paused is not None:
            return
        loop = asyncio.get_running_loop()
        loop.remove_reader(sock.fileno())

        def resume() -> None:
            self._paused = None
            if self._sock is not None:
                loop.add_reader(self._sock.fileno(), self._accept)

        self._paused = loop.call_later(seconds, resume)


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
