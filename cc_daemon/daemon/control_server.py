"""The control socket: the one way to release a stranded station by hand.

When a witness of home is broken (a switch or an encoder), the winch can never
verify home, and the daemon holds the station with `R-L` for ever. An operator
who has seen the probe on board releases it with `cc-daemon release --reason
TEXT`: this socket, `control.sock` beside the status socket, takes one line
`release <reason>` and answers one line of JSON (`{"ok": ..., "message": ...}`).
`home` asks the daemon to haul a stranded probe in (`cc-daemon winch home`
while the daemon runs): the station ends, with R-F, only if the winch then
verifies home.

Who may use it: the socket is mode 0660 (the daemon's user and its group, the
service's admin group), and the peer's credentials (SO_PEERCRED) are checked
again: root, the daemon's own user, or a member of the socket's group. Every
request, refused or not, is logged with the peer's uid and pid; a release is
journaled by the daemon (`operator_release`).

It must never block the event loop or raise into the daemon; it changes nothing
itself: it hands the request to `release` and reports its answer.
"""

from __future__ import annotations

import asyncio
import contextlib
import grp
import json
import os
import pwd
import socket
import struct
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import structlog

from cc_daemon.config.statuspaths import daemon_socket_path
from cc_daemon.daemon.status_server import SOCKET_MODE, _clear_stale, serve_until_cancelled

if TYPE_CHECKING:
    from cc_daemon.config import StatusSettings

_log = structlog.get_logger("cc_daemon.control")

CONTROL_NAME = "control.sock"
MAX_REQUEST = 512  # "release " and a reason: a line, never more
REQUEST_TIMEOUT_S = 2.0
_PEERCRED = struct.Struct("3i")


class Peer(NamedTuple):
    pid: int
    uid: int
    gid: int


# (peer, reason) -> (done, message)
Release = Callable[[Peer, str], tuple[bool, str]]


def control_path(status_path: Path) -> Path:
    """The control socket beside a status socket, named after it: `status.sock` →
    `control.sock`, `<journal>.status.sock` → `<journal>.control.sock` (two daemons
    on two journals in one directory never share one)."""
    name = status_path.name
    if name.endswith("status.sock"):
        return status_path.with_name(name[: -len("status.sock")] + CONTROL_NAME)
    return status_path.with_name(f"{name}.{CONTROL_NAME}")


def _peer(writer: asyncio.StreamWriter) -> Peer | None:
    sock = writer.get_extra_info("socket")
    if sock is None:
        return None
    raw = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _PEERCRED.size)
    return Peer(*_PEERCRED.unpack(raw))


def authorised(peer: Peer, socket_gid: int) -> bool:
    """Root, the daemon's own user, or a member of the socket's group."""
    if peer.uid in (0, os.getuid()) or peer.gid == socket_gid:
        return True
    try:
        name = pwd.getpwuid(peer.uid).pw_name
        return socket_gid in os.getgrouplist(name, peer.gid)
    except KeyError:
        return False


class ControlServer:
    def __init__(self, path: Path, release: Release, home: Release | None = None) -> None:
        self.path = path
        self._release = release
        self._home = home
        self._server: asyncio.Server | None = None

    async def start(self) -> None:
        _clear_stale(self.path)
        self._server = await asyncio.start_unix_server(self._serve_one, path=str(self.path))
        os.chmod(self.path, SOCKET_MODE)
        _log.info("control socket open", path=str(self.path))

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()

    async def _serve_one(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            answer = await self._answer(reader, writer)
            writer.write(json.dumps(answer).encode() + b"\n")
            await writer.drain()
        except Exception as exc:  # a client's trouble never reaches the daemon
            _log.warning("control request failed", error=f"{type(exc).__name__}: {exc}")
        finally:
            writer.close()

    async def _answer(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> dict[str, object]:
        peer = _peer(writer)
        gid = os.stat(self.path).st_gid
        if peer is None or not authorised(peer, gid):
            group = _group_name(gid)
            _log.warning("control request refused: not authorised", peer=peer)
            return {"ok": False, "message": f"not authorised: root or group {group} only"}
        async with asyncio.timeout(REQUEST_TIMEOUT_S):
            line = await reader.readline()
        text = line[:MAX_REQUEST].decode("utf-8", "replace").strip()
        verb, _, reason = text.partition(" ")
        reason = reason.strip()
        if verb == "home" and self._home is not None:
            ok, message = self._home(peer, reason or "operator request")
        elif verb == "release" and reason:
            ok, message = self._release(peer, reason)
        else:
            return {"ok": False, "message": "expected one line: release <reason>, or home"}
        return {"ok": ok, "message": message}


def _group_name(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


async def serve_control(
    settings: StatusSettings,
    release: Release,
    home: Release | None = None,
    *,
    journal: Path | None = None,
) -> None:
    """The daemon's control duty, beside the status socket (none without one); a
    socket that cannot be bound (another daemon's) is said and retried, never a crash."""
    status_path = daemon_socket_path(settings, journal=journal) if settings.enabled else None
    if status_path is None:
        await asyncio.Future()
        return
    await serve_until_cancelled(ControlServer(control_path(status_path), release, home), "control")
