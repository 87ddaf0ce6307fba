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
service's admin group), and the peer's credentials are checked again, from the
kernel (SO_PEERCRED, SO_PEERGROUPS: no name look-up that could fail when
descriptors run short): root, the daemon's own user, or a member of the
socket's group. Every connection gets a one-line answer, a refusal included
(sent as it is accepted; the client reads it even when its own request could not
be sent: `cli.daemon_socket.exchange`); an admitted request is read before the
answer, and what follows it is drained before closing. The bounds:
`MAX_CONNECTIONS` at once, `PER_PEER` of one user, within the descriptors the
daemon keeps (`admission`); `REQUEST_BURST` connections of one user at once,
then `REQUESTS_PER_MINUTE`; `ACCEPTS_PER_S` accepted in all; one line of
`control_request.MAX_REQUEST` bytes within `REQUEST_TIMEOUT_S`.
Whom the access rule refuses is answered at once, before any of these counts it.
A release or a haul is logged with the peer's uid and pid and journaled by the
daemon (`operator_release`, `operator_haul_in`); refusals are logged with the
uid, once a minute with their count (`socket_listener.Refusals`).

It must never block the event loop or raise into the daemon; it changes nothing
itself: it hands the request to `release` or `home` and reports their answer.
"""

from __future__ import annotations

import asyncio
import grp
import json
import os
import pwd
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import structlog

from cc_daemon.config.statuspaths import daemon_socket_path
from cc_daemon.daemon.admission import SHARED, Admission, DescriptorBudget, RequestRate, Ticket
from cc_daemon.daemon.control_request import MAX_REQUEST, Request, parse
from cc_daemon.daemon.socket_listener import Listener, directory_problem, serve_until_cancelled
from cc_daemon.ground.peercred import Peer, peer_groups

if TYPE_CHECKING:
    from cc_daemon.config import StatusSettings

__all__ = ["ControlServer", "Peer", "authorised", "control_path", "serve_control"]

_log = structlog.get_logger("cc_daemon.control")

CONTROL_NAME = "control.sock"
REQUEST_TIMEOUT_S = 2.0
MAX_CONNECTIONS = 16
PER_PEER = 4
REQUESTS_PER_MINUTE = 10
REQUEST_BURST = 5
# Connections accepted a second, refused ones included: people use this socket, a
# few times a minute; a client connecting in a loop, or pushing a megabyte with
# each connection, is slowed down to this (benchmarks/socket_attacks.py).
ACCEPTS_PER_S = 100.0
MAX_DISCARD = 64 * 1024  # read after the answer, so that closing does not reset it
_GROUPS_TTL_S = 60.0

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


def authorised(peer: Peer, socket_gid: int, groups: frozenset[int] | None = None) -> bool:
    """Root, the daemon's own user, or a member of the socket's group: by the peer's
    primary group, its supplementary `groups` (SO_PEERGROUPS), or where the kernel
    could not say (None), by its name's groups (looked up, then kept a minute)."""
    if peer.uid in (0, os.getuid()) or peer.gid == socket_gid:
        return True
    if groups is None:
        groups = _named_groups(peer.uid, peer.gid)
    return socket_gid in groups


_groups_cache: dict[tuple[int, int], tuple[float, frozenset[int]]] = {}


def _named_groups(uid: int, gid: int) -> frozenset[int]:
    now = time.monotonic()
    cached = _groups_cache.get((uid, gid))
    if cached is not None and now - cached[0] < _GROUPS_TTL_S:
        return cached[1]
    try:
        groups = frozenset(os.getgrouplist(pwd.getpwuid(uid).pw_name, gid))
    except (KeyError, OSError):
        return frozenset()  # not kept: a look-up that failed may succeed next time
    if len(_groups_cache) > 256:
        _groups_cache.clear()
    _groups_cache[(uid, gid)] = (now, groups)
    return groups


def _answer_line(ok: bool, message: str) -> bytes:
    return json.dumps({"ok": ok, "message": message}).encode() + b"\n"


class ControlServer:
    def __init__(
        self,
        path: Path,
        release: Release,
        home: Release | None = None,
        *,
        budget: DescriptorBudget = SHARED,
    ) -> None:
        self._release = release
        self._home = home
        rate = RequestRate(REQUESTS_PER_MINUTE, REQUEST_BURST)
        self._listener = Listener(
            path,
            self._accepted,
            Admission(MAX_CONNECTIONS, PER_PEER, budget, rate=rate),
            what="control",
            refuse=self._busy,
            vet=self._vet,
            accepts_per_s=ACCEPTS_PER_S,
        )
        self._group = ""
        self._gid = -1

    @property
    def path(self) -> Path:
        return self._listener.path

    async def start(self) -> None:
        await self._listener.start()
        # Resolved now, while descriptors are plenty: the refusal names the group.
        self._gid = os.stat(self.path).st_gid
        self._group = _group_name(self._gid)
        _log.info("control socket open", path=str(self.path))

    async def close(self) -> None:
        await self._listener.close()

    def _busy(self, peer: Peer, why: str) -> bytes:
        return _answer_line(False, f"busy ({why} on the control socket): try again")

    def _vet(self, conn: socket.socket, peer: Peer) -> tuple[str, bytes] | None:
        """Refuse at once, before any cap or rate counts it, whom the socket's
        access rule refuses: the answer is always "not authorised"."""
        if authorised(peer, self._gid, peer_groups(conn)):
            return None
        message = f"not authorised: root or group {self._group} only"
        return "not authorised", _answer_line(False, message)

    def _accepted(self, conn: socket.socket, peer: Peer, place: Ticket) -> None:
        self._listener.serve(conn, peer, place, self._serve_one, limit=MAX_REQUEST + 1)

    async def _serve_one(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, peer: Peer, _: Ticket
    ) -> None:
        ok, message = await self._answer(reader, peer)
        writer.write(_answer_line(ok, message))
        try:
            async with asyncio.timeout(REQUEST_TIMEOUT_S):
                await writer.drain()
                writer.write_eof()
                discarded = 0
                while discarded <= MAX_DISCARD and (chunk := await reader.read(4096)):
                    discarded += len(chunk)
        except (TimeoutError, OSError):
            pass

    async def _answer(self, reader: asyncio.StreamReader, peer: Peer) -> tuple[bool, str]:
        request = await _read_request(reader)
        if isinstance(request, str):
            return False, request
        if request.verb == "home" and self._home is not None:
            return self._home(peer, request.reason or "operator request")
        if request.verb == "release":
            return self._release(peer, request.reason)
        return False, "home: this daemon has no winch to haul in"


async def _read_request(reader: asyncio.StreamReader) -> Request | str:
    try:
        async with asyncio.timeout(REQUEST_TIMEOUT_S):
            line = await reader.readuntil(b"\n")
    except asyncio.IncompleteReadError as exc:
        line = exc.partial  # the client closed its end after the line, unterminated
    except asyncio.LimitOverrunError:
        return f"request too long: one line of at most {MAX_REQUEST} bytes"
    except TimeoutError:
        return f"no request within {REQUEST_TIMEOUT_S:g} s"
    return parse(line.rstrip(b"\n"))


def _group_name(gid: int) -> str:
    try:
        return grp.getgrgid(gid).gr_name
    except (KeyError, OSError):
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
    if status_path is None or directory_problem(status_path) is not None:
        await asyncio.Future()  # the status duty says why
        return
    await serve_until_cancelled(ControlServer(control_path(status_path), release, home), "control")
