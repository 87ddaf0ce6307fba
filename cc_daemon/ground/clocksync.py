"""Is the system clock synchronised? Asked of the kernel, read-only.

`adjtimex(2)` with `modes = 0` changes nothing and returns the kernel's NTP
state: the `STA_UNSYNC` status bit (set until a time daemon has disciplined the
clock) and `maxerror`, the bound on the clock's error it maintains. The unit
allows this read back (`SystemCallFilter=adjtimex clock_adjtime`, no capability to
set anything); where it is refused all the same (another sandbox), the call
fails and systemd-timesyncd's flag file answers instead.

This module never sets the clock and never raises: an answer it cannot get is
`synchronised=None`.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os
from dataclasses import dataclass

STA_UNSYNC = 0x0040
TIME_ERROR = 5  # adjtimex's return: the clock is not synchronised
TIMESYNC_FLAG = "/run/systemd/timesync/synchronized"


class _Timex(ctypes.Structure):
    # struct timex from <sys/timex.h> (glibc, native longs; 11 reserved ints).
    _fields_ = [
        ("modes", ctypes.c_uint),
        ("offset", ctypes.c_long),
        ("freq", ctypes.c_long),
        ("maxerror", ctypes.c_long),
        ("esterror", ctypes.c_long),
        ("status", ctypes.c_int),
        ("constant", ctypes.c_long),
        ("precision", ctypes.c_long),
        ("tolerance", ctypes.c_long),
        ("time_sec", ctypes.c_long),
        ("time_usec", ctypes.c_long),
        ("tick", ctypes.c_long),
        ("ppsfreq", ctypes.c_long),
        ("jitter", ctypes.c_long),
        ("shift", ctypes.c_int),
        ("stabil", ctypes.c_long),
        ("jitcnt", ctypes.c_long),
        ("calcnt", ctypes.c_long),
        ("errcnt", ctypes.c_long),
        ("stbcnt", ctypes.c_long),
        ("tai", ctypes.c_int),
        ("reserved", ctypes.c_int * 11),
    ]


@dataclass(frozen=True, slots=True)
class ClockSync:
    synchronised: bool | None  # None: could not be told
    max_error_s: float | None  # the kernel's bound on the clock's error
    source: str  # "adjtimex", "timesyncd" or "unknown"
    detail: str = ""

    def as_dict(self) -> dict[str, object]:
        return {
            "synchronised": self.synchronised,
            "max_error_s": self.max_error_s,
            "source": self.source,
            "detail": self.detail,
        }


def from_adjtimex(returned: int, status: int, maxerror_us: int) -> ClockSync:
    """Interpret what adjtimex returned (pure: the tests feed it planted values)."""
    synced = returned != TIME_ERROR and not status & STA_UNSYNC
    detail = "" if synced else "the kernel marks the clock unsynchronised (STA_UNSYNC)"
    return ClockSync(synced, maxerror_us / 1e6, "adjtimex", detail)


@functools.cache
def _libc() -> ctypes.CDLL:
    # The C library this process already has (dlopen(NULL)): instant, where
    # find_library runs ldconfig in a subprocess, and the journal asks this
    # question from the daemon's event loop. Once per process either way.
    here = ctypes.CDLL(None, use_errno=True)
    if hasattr(here, "adjtimex"):
        return here
    return ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)


def read_adjtimex() -> tuple[int, int, int]:
    """(return value, status, maxerror µs) of a read-only adjtimex; OSError if refused."""
    libc = _libc()
    timex = _Timex()  # modes = 0: read only
    returned = int(libc.adjtimex(ctypes.byref(timex)))
    if returned < 0:
        errno = ctypes.get_errno()
        raise OSError(errno, os.strerror(errno))
    return returned, int(timex.status), int(timex.maxerror)


def clock_sync(flag_path: str = TIMESYNC_FLAG) -> ClockSync:
    try:
        return from_adjtimex(*read_adjtimex())
    except (OSError, AttributeError) as exc:
        refused = f"adjtimex refused ({exc}); "
    synced = os.path.exists(flag_path)
    return ClockSync(synced, None, "timesyncd", refused + ("" if synced else f"no {flag_path}"))
