"""Asking the daemon's own sockets, and only them: the client side of the status
and control sockets (`cc-daemon status`, `release`, `winch home`, `doctor`, `web`).

Before a word is read, `connect` makes sure it is the daemon that answers:
- a socket whose directory another user could write is refused without
  connecting (`statuspaths.shared_directory`: /tmp, or another user's directory);
- once connected, the peer (SO_PEERCRED) must be the daemon's user, which a
  client knows as: root, the service's user (`cc-daemon`, if there is one), or
  yourself (a daemon you started by hand). Anyone else is refused.

Its errors say which of four things happened, because each means something
else to a command, `winch home` above all (it drives the winch itself only
when no daemon can be running: `NoDaemon`):
- `NoDaemon`: no socket there, or nobody listening on it;
- `NotAuthorised`: the socket is there and refuses you (permission denied);
- `NotTheDaemon`: someone else answers there, or could: refused, never believed;
- `Unreachable`: anything else (no answer in time, a reset).

It never writes to a socket it has not checked, and never waits past its timeout.
"""

from __future__ import annotations

import contextlib
import errno
import os
import pwd
import socket
import struct
import time
from pathlib import Path

from cc_daemon.config.statuspaths import SERVICE_USER, shared_directory
from cc_daemon.core.errors import CcDaemonError
from cc_daemon.ground.peercred import peer_credentials

GROUP_HINT = "sudo usermod -aG cc-daemon $USER, then log in again"
_TIMEVAL = struct.Struct("ll")  # struct timeval: time_t and suseconds_t, native longs


class SocketTrouble(CcDaemonError):
    """The daemon's socket could not be asked; the message says why."""


class NoDaemon(SocketTrouble):
    """Nothing listens at the path: no daemon is running there."""


class NoSocket(NoDaemon):
    """Nothing at all at the path."""


class NotAuthorised(SocketTrouble):
    """The socket is there and refuses this user."""


class NotTheDaemon(SocketTrouble):
    """Someone other than the daemon answers there, or could."""


class Unreachable(SocketTrouble):
    """The socket is there but gave no usable answer."""


def trusted_uids() -> frozenset[int]:
    """Whom a client believes: root, the service's user, and the user running it."""
    uids = {0, os.geteuid()}
    with contextlib.suppress(KeyError):  # not installed: a daemon by hand is yours
        uids.add(pwd.getpwnam(SERVICE_USER).pw_uid)
    return frozenset(uids)


def _user(uid: int) -> str:
    try:
        return f"uid {uid} ({pwd.getpwuid(uid).pw_name})"
    except KeyError:
        return f"uid {uid}"


def connect(path: Path, timeout_s: float) -> socket.socket:
    """A connection to the daemon's socket at `path`, its peer checked; raises a
    `SocketTrouble`. A listen backlog that is full (a busy daemon) is waited for in
    the kernel's queue, up to the timeout."""
    trusted = trusted_uids()
    problem = shared_directory(path, trusted)
    if problem is not None:
        raise NotTheDaemon(f"refusing {path}: {problem}, so anyone could answer there")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        # Blocking, bounded by SO_SNDTIMEO: a socket with a timeout would fail at
        # once (EAGAIN) on a full backlog instead of queueing for it.
        seconds = max(timeout_s, 0.001)
        whole = int(seconds)
        sock.setsockopt(
            socket.SOL_SOCKET,
            socket.SO_SNDTIMEO,
            _TIMEVAL.pack(whole, int((seconds - whole) * 1e6)),
        )
        sock.connect(str(path))
        sock.settimeout(seconds)
        peer = peer_credentials(sock)
    except BlockingIOError:
        sock.close()
        raise Unreachable(
            f"{path}: the daemon is too busy to accept (waited {timeout_s:g} s)"
        ) from None
    except OSError as exc:
        sock.close()
        raise _trouble(path, exc, timeout_s) from None
    except BaseException:
        sock.close()
        raise
    if peer.uid not in trusted:
        sock.close()
        raise NotTheDaemon(
            f"refusing {path}: it is answered by {_user(peer.uid)}, not by the daemon's"
            f" user ({SERVICE_USER}), root or you"
        )
    return sock


def _trouble(path: Path, exc: OSError, timeout_s: float) -> SocketTrouble:
    if isinstance(exc, FileNotFoundError | NotADirectoryError):
        return NoSocket(f"no socket at {path}")
    if isinstance(exc, ConnectionRefusedError):
        return NoDaemon(f"{path}: nobody answers (the daemon is not running)")
    if isinstance(exc, PermissionError) or exc.errno == errno.EPERM:
        return NotAuthorised(
            f"{path}: not authorised (permission denied): root, the daemon's user or"
            f" its group only ({GROUP_HINT})"
        )
    if isinstance(exc, TimeoutError):
        return Unreachable(f"{path}: no answer within {timeout_s:g} s")
    return Unreachable(f"{path}: {exc.strerror or exc}")


def exchange(path: Path, request: bytes, timeout_s: float, max_answer: int) -> bytes:
    """Send `request` (b"": nothing) and read the answer to its end, at most
    `max_answer` bytes. A daemon that answered and closed before taking all of the
    request (a refusal) is still heard: its answer is read, not the broken pipe."""
    deadline = time.monotonic() + timeout_s
    with connect(path, timeout_s) as sock:
        if request:
            try:
                sock.sendall(request)
            except (BrokenPipeError, ConnectionResetError):
                pass  # answered and closed already: the answer waits to be read
            except TimeoutError:
                raise Unreachable(f"{path}: no answer within {timeout_s:g} s") from None
        chunks: list[bytes] = []
        size = 0
        try:
            while True:
                sock.settimeout(max(deadline - time.monotonic(), 0.001))
                chunk = sock.recv(65536)
                if not chunk:
                    break
                size += len(chunk)
                if size > max_answer:
                    raise Unreachable(f"{path}: the answer is larger than {max_answer} bytes")
                chunks.append(chunk)
        except ConnectionResetError:
            pass  # what was sent before the reset is the answer
        except TimeoutError:
            raise Unreachable(f"{path}: no answer within {timeout_s:g} s") from None
        except OSError as exc:
            raise Unreachable(f"{path}: {exc.strerror or exc}") from None
    return b"".join(chunks)
