"""Who is at the other end of a connected unix socket, as the kernel says.

`peer_credentials` reads SO_PEERCRED (the pid, uid and gid of the process that
connected, or of the one that listened); `peer_groups` reads SO_PEERGROUPS, the
peer's supplementary groups. Both come from the kernel with the socket: no
look-up in /etc/passwd or /etc/group, so no descriptor is opened and nothing
fails when the process is short of descriptors, and no name service can be
asked to lie.

It must never block, open a file or ask a name service.
"""

from __future__ import annotations

import socket
import struct
import sys
from typing import NamedTuple, Protocol

_PEERCRED = struct.Struct("3i")
# Not in Python's socket module; 59 on every architecture Linux runs the Pi on
# (asm-generic), x86 included.
SO_PEERGROUPS = getattr(socket, "SO_PEERGROUPS", 59)
# Python's getsockopt takes at most 1024 bytes: 256 groups. A peer with more gets
# None, and its groups are looked up by name instead.
_GROUPS_BUFFER = 1024


class _Socket(Protocol):
    """A connected socket, or asyncio's view of one (`get_extra_info("socket")`)."""

    def getsockopt(self, level: int, option: int, buflen: int, /) -> bytes: ...


class Peer(NamedTuple):
    pid: int
    uid: int
    gid: int


def peer_credentials(sock: _Socket) -> Peer:
    """The peer's pid, uid and gid (SO_PEERCRED). Raises OSError."""
    raw = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _PEERCRED.size)
    return Peer(*_PEERCRED.unpack(raw))


def peer_groups(sock: _Socket) -> frozenset[int] | None:
    """The peer's supplementary groups (SO_PEERGROUPS, Linux 4.13 and later); None
    where the kernel cannot say (an older kernel, more than 256 groups)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, SO_PEERGROUPS, _GROUPS_BUFFER)
    except OSError:
        return None
    count = len(raw) // 4
    return frozenset(struct.unpack(f"{count}I", raw[: count * 4]))
