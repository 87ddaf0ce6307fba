"""A pseudo-terminal pair that stands in for the autopilot's serial cable.

This module owns the pty pair used by `--simulate` and the end-to-end tests:
both ends in raw mode (so every byte value crosses unchanged, nothing echoes,
no byte is a signal or flow-control character), a symlink the daemon opens as
if it were `/dev/ttyUSB0`, and the "USB adapter pulled out / plugged back in"
operations.

It keeps its own descriptor of the slave open for the pair's whole life, so
the master never reads EIO merely because the daemon closed the port while it
reconnects. It never reads or writes frames (that is `cc_daemon.sim.port`) and
never touches a descriptor it did not open.
"""

from __future__ import annotations

import contextlib
import os
import termios
from pathlib import Path
from types import TracebackType

# termios attribute list indices (see termios.tcgetattr)
_IFLAG, _OFLAG, _CFLAG, _LFLAG, _CC = 0, 1, 2, 3, 6


def make_raw(fd: int) -> None:
    """Put a terminal in raw mode, like cfmakeraw(3) plus software flow control off.

    `tty.setraw` leaves INLCR, IGNCR, PARMRK, IXOFF and ECHONL alone; a serial
    line carrying binary frames needs every one of them off.
    """
    attrs = termios.tcgetattr(fd)
    attrs[_IFLAG] &= ~(
        termios.IGNBRK
        | termios.BRKINT
        | termios.PARMRK
        | termios.ISTRIP
        | termios.INLCR
        | termios.IGNCR
        | termios.ICRNL
        | termios.IXON
        | termios.IXOFF
        | termios.IXANY
        | termios.INPCK
    )
    attrs[_OFLAG] &= ~termios.OPOST
    attrs[_LFLAG] &= ~(
        termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN
    )
    attrs[_CFLAG] &= ~(termios.CSIZE | termios.PARENB)
    attrs[_CFLAG] |= termios.CS8 | termios.CREAD | termios.CLOCAL
    cc = list(attrs[_CC])
    cc[termios.VMIN] = 1
    cc[termios.VTIME] = 0
    attrs[_CC] = cc
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


class PtyPair:
    """A pseudo-terminal pair standing in for a serial cable.

    `path` is a symlink to the slave end: give it to the daemon as its serial
    port. `master_fd` is the autopilot's end, non-blocking. The pair is live
    from construction until `unplug()` or `close()`.
    """

    def __init__(self, link_path: Path) -> None:
        self.path = Path(link_path)
        self.master_fd = -1
        self._slave_fd = -1
        self.slave_name = ""
        self.plugged = False
        self._open()

    # ------------------------------------------------------------ lifecycle

    def _open(self) -> None:
        master, slave = os.openpty()
        try:
            make_raw(master)
            make_raw(slave)
            os.set_blocking(master, False)
            name = os.ttyname(slave)
            self._point_link_at(name)
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        self.master_fd = master
        self._slave_fd = slave
        self.slave_name = name
        self.plugged = True

    def _point_link_at(self, target: str) -> None:
        # Build the new link beside the old one and rename it over: whoever
        # opens `path` sees the old pty or the new one, never nothing.
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(target)
        os.replace(tmp, self.path)

    def unplug(self) -> None:
        """Pull the cable: close both of our ends and remove the symlink.

        Whoever still has the slave open reads EIO (a hang-up) from now on,
        and opening `path` fails with FileNotFoundError until `replug()`.
        """
        if not self.plugged:
            return
        self.plugged = False
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
        master, slave = self.master_fd, self._slave_fd
        self.master_fd = self._slave_fd = -1
        os.close(master)
        os.close(slave)

    def replug(self) -> None:
        """Plug a cable back in: a new pty pair behind the same `path`.

        `master_fd` changes; any reader over the old one must be replaced.
        Replugging a pair that is still plugged unplugs it first.
        """
        self.unplug()
        self._open()

    def close(self) -> None:
        """Unplug for good. Safe to call more than once."""
        self.unplug()

    def __enter__(self) -> PtyPair:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = f"{self.path} -> {self.slave_name}" if self.plugged else f"{self.path} unplugged"
        return f"PtyPair({state})"
