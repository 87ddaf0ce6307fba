"""Which other processes have a device open: the answer `decode --port` needs.

A second reader on a UART steals bytes from the first (each byte goes to one
reader only), and root bypasses the exclusive lock the daemon takes. So before
sniffing a port, `cc-daemon decode --port` asks who else has it open: every
`/proc/<pid>/fd/<n>` that resolves to the same device (or file). Processes we
may not look into (another user's, without root) are skipped: the answer can
say "someone has it" but never prove "nobody has it".

It only reads /proc; it never opens the device itself.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass
from pathlib import Path

__all__ = ["PortUser", "port_users"]


@dataclass(frozen=True, slots=True)
class PortUser:
    pid: int
    command: str  # the process's name (`comm`), or "?" if it could not be read

    def __str__(self) -> str:
        return f"pid {self.pid} ({self.command})"


def _identity(info: os.stat_result) -> tuple[int, int, int]:
    # A device is the same device whatever node names it (a symlink, /dev/serial0).
    if stat.S_ISCHR(info.st_mode) or stat.S_ISBLK(info.st_mode):
        return (0, 0, info.st_rdev)
    return (1, info.st_dev, info.st_ino)


def port_users(
    port: str, *, proc: Path = Path("/proc"), exclude_pid: int | None = None
) -> list[PortUser]:
    """The processes (other than `exclude_pid`, default this one) that have `port` open."""
    try:
        wanted = _identity(os.stat(port))
    except (OSError, ValueError):
        return []  # nothing there (yet): nobody can have it open
    me = os.getpid() if exclude_pid is None else exclude_pid
    users: list[PortUser] = []
    try:
        entries = list(os.scandir(proc))
    except OSError:
        return []
    for entry in entries:
        if not entry.name.isdigit() or int(entry.name) == me:
            continue
        fd_dir = Path(entry.path) / "fd"
        try:
            fds = os.listdir(fd_dir)
        except OSError:
            continue  # gone, or not ours to look at
        for fd in fds:
            try:
                if _identity(os.stat(fd_dir / fd)) == wanted:
                    users.append(PortUser(int(entry.name), _command(Path(entry.path))))
                    break
            except OSError:
                continue
    return users


def _command(process: Path) -> str:
    try:
        return (process / "comm").read_text().strip() or "?"
    except OSError:
        return "?"
