"""systemd service notification (sd_notify), without a C library.

Under `Type=notify` systemd passes a datagram socket in `NOTIFY_SOCKET`; the
daemon sends `READY=1` once it answers the autopilot, `STATUS=...` lines an
operator sees in `systemctl status`, `STOPPING=1` on shutdown and, when the
unit sets `WatchdogSec=`, `WATCHDOG=1` pings (at half the interval systemd
gives: `ping_every_s`). Outside systemd every call is a no-op. Sending never
raises: a notification is never worth stopping the boat.
"""

from __future__ import annotations

import os
import socket

import structlog

_log = structlog.get_logger("cc_daemon.systemd")


# With the watchdog on and no interval known (a test), a ping every second.
DEFAULT_PING_S = 1.0


class SystemdNotifier:
    def __init__(
        self, address: str | None, watchdog: bool = False, watchdog_s: float | None = None
    ) -> None:
        """`watchdog_s`: the unit's WatchdogSec (systemd's WATCHDOG_USEC), if known."""
        if address and address.startswith("@"):  # abstract socket namespace
            address = "\0" + address[1:]
        self._address = address or None
        self._watchdog = watchdog
        self._watchdog_s = watchdog_s if watchdog_s is not None and watchdog_s > 0 else None
        self._socket: socket.socket | None = None
        # Put before every STATUS= line (a simulated winch outside --simulate says so
        # in `systemctl status`, whatever else the status says).
        self.status_prefix = ""

    @classmethod
    def from_environment(cls) -> SystemdNotifier:
        usec = os.environ.get("WATCHDOG_USEC", "")
        watchdog = bool(usec) and (
            os.environ.get("WATCHDOG_PID", str(os.getpid())) == str(os.getpid())
        )
        watchdog_s = int(usec) / 1e6 if usec.isdigit() else None
        return cls(os.environ.get("NOTIFY_SOCKET"), watchdog, watchdog_s)

    @property
    def enabled(self) -> bool:
        return self._address is not None

    def notify(self, *lines: str) -> None:
        if self._address is None:
            return
        if self.status_prefix:
            prefix = "STATUS=" + self.status_prefix
            lines = tuple(prefix + ln[7:] if ln.startswith("STATUS=") else ln for ln in lines)
        try:
            if self._socket is None:
                self._socket = socket.socket(
                    socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC
                )
            self._socket.sendto("\n".join(lines).encode(), self._address)
        except OSError as exc:
            _log.warning("systemd notification failed", error=str(exc))

    @property
    def ping_every_s(self) -> float | None:
        """How often `watchdog` must be called: half of WatchdogSec (None: never)."""
        if not self._watchdog or self._address is None:
            return None
        return self._watchdog_s / 2 if self._watchdog_s is not None else DEFAULT_PING_S

    def watchdog(self) -> None:
        if self._watchdog:
            self.notify("WATCHDOG=1")

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None
