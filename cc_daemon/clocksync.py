"""Whether the wall clock is synchronised, as the kernel itself sees it.

This module owns the answer behind every record's `clock_synced`. Every time
daemon (systemd-timesyncd, chrony, ntpd, chrony fed by gpsd on a boat far from
any network) disciplines the kernel's clock through adjtimex(2): it clears the
kernel's STA_UNSYNC status bit once it has a sync and keeps resetting the
kernel's maximum-error estimate, which the kernel grows by 500 ppm in between
and which makes the kernel set STA_UNSYNC again by itself past 16 s. So the
kernel's view is right whichever daemon runs, where systemd-timesyncd's flag
file is only right under timesyncd (a Pi on chrony or on GPS time was always
"unsynchronised").

The clock is synchronised when adjtimex answers with no TIME_ERROR state, the
STA_UNSYNC bit clear, and a maximum error under `MAX_ERROR_S`. The call is
made with `modes = 0`: it reads, changes nothing and needs no privilege. This
module never sets the clock. Where adjtimex cannot be called (not Linux, no
libc), it falls back to timesyncd's flag file.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

TIMESYNC_FLAG = Path("/run/systemd/timesync/synchronized")
STA_UNSYNC = 0x0040  # <linux/timex.h>: the clock is not synchronised
TIME_ERROR = 5  # adjtimex's return value for a clock not synchronised
# The kernel gives up itself at 16 s (NTP_PHASE_LIMIT). A daemon in sync keeps
# the estimate far lower: timesyncd resets it to 0 at each poll, and even its
# longest poll (2048 s) lets it grow to only about 1 s at 500 ppm.
MAX_ERROR_S = 5.0


Adjtimex = Callable[[Any], int]  # takes a `struct timex` buffer, returns the clock state


class _Timex(ctypes.Structure):
    """`struct timex` of <sys/timex.h>, as glibc's `adjtimex` takes it (longs are the
    platform's: 64-bit on a 64-bit Pi OS, 32-bit on armhf, as the symbol expects)."""

    _fields_ = [
        ("modes", ctypes.c_uint),
        ("offset", ctypes.c_long),
        ("freq", ctypes.c_long),
        ("maxerror", ctypes.c_long),  # microseconds
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
        ("_reserved", ctypes.c_int * 11),
    ]


@dataclass(frozen=True, slots=True)
class KernelClock:
    """What adjtimex said: its return value, the status bits, the maximum error."""

    state: int  # TIME_OK (0) .. TIME_ERROR (5)
    status: int
    maxerror_us: int

    @property
    def synced(self) -> bool:
        return (
            self.state != TIME_ERROR
            and not self.status & STA_UNSYNC
            and self.maxerror_us < MAX_ERROR_S * 1_000_000
        )


def _libc_adjtimex() -> Adjtimex | None:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        function = libc.adjtimex
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_void_p]
    function.restype = ctypes.c_int
    return function  # type: ignore[no-any-return,unused-ignore]


def read_kernel_clock(
    adjtimex: Adjtimex | None = None,
) -> KernelClock | None:
    """The kernel's clock status (adjtimex with modes 0); None where it cannot be had."""
    call = adjtimex if adjtimex is not None else _ADJTIMEX
    if call is None:
        return None
    buffer = ctypes.create_string_buffer(ctypes.sizeof(_Timex))  # zeroed: modes = 0, read only
    state = call(buffer)
    if state < 0:
        return None
    timex = _Timex.from_buffer(buffer)
    return KernelClock(state, timex.status, timex.maxerror)


def clock_synced(
    read: Callable[[], KernelClock | None] = read_kernel_clock,
    flag: Path = TIMESYNC_FLAG,
) -> bool:
    """Whether the wall clock is synchronised: the kernel's view, else timesyncd's flag."""
    kernel = read()
    if kernel is not None:
        return kernel.synced
    return os.path.exists(flag)


_ADJTIMEX = _libc_adjtimex()
