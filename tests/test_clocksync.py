"""The kernel's view of the clock: adjtimex's status bit and maximum error."""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path
from typing import Any

import pytest

from cc_daemon import clocksync
from cc_daemon.clocksync import STA_UNSYNC, TIME_ERROR, KernelClock, clock_synced, read_kernel_clock

TIME_OK = 0
STA_PLL = 0x0001


def fake_adjtimex(state: int, status: int, maxerror_us: int) -> clocksync.Adjtimex:
    """An adjtimex that fills the `struct timex` as the kernel would, and checks it was
    asked to change nothing (modes 0)."""

    def call(buffer: Any) -> int:
        timex = clocksync._Timex.from_buffer(buffer)
        assert timex.modes == 0  # read-only: never ADJ_* anything
        timex.status = status
        timex.maxerror = maxerror_us
        return state

    return call


@pytest.mark.parametrize(
    ("state", "status", "maxerror_us", "synced"),
    [
        (TIME_OK, STA_PLL, 12_000, True),  # chrony or timesyncd, in sync
        (TIME_OK, STA_PLL | STA_UNSYNC, 12_000, False),  # the daemon says: no sync yet
        (TIME_ERROR, STA_UNSYNC, 16_000_000, False),  # a fresh boot, nobody disciplining
        (TIME_OK, STA_PLL, 5_000_000, False),  # in sync once, drifting for hours since
        (TIME_OK, STA_PLL, 4_999_999, True),
        (TIME_ERROR, 0, 0, False),
    ],
)
def test_the_kernel_status_decides(state: int, status: int, maxerror_us: int, synced: bool) -> None:
    kernel = read_kernel_clock(fake_adjtimex(state, status, maxerror_us))
    assert kernel == KernelClock(state, status, maxerror_us)
    assert kernel.synced is synced
    flag_says_yes = Path(__file__)  # exists: must not matter when the kernel answers
    assert clock_synced(lambda: kernel, flag=flag_says_yes) is synced


def test_without_adjtimex_the_timesyncd_flag_file_is_the_answer(tmp_path: Path) -> None:
    flag = tmp_path / "synchronized"
    assert clock_synced(lambda: None, flag=flag) is False
    flag.touch()
    assert clock_synced(lambda: None, flag=flag) is True
    assert read_kernel_clock(lambda buffer: -1) is None  # EPERM, EINVAL: no answer


@pytest.mark.skipif(sys.platform != "linux", reason="adjtimex is Linux's")
def test_the_real_kernel_answers_and_is_left_unchanged() -> None:
    first = read_kernel_clock()
    assert first is not None
    assert 0 <= first.state <= TIME_ERROR
    assert first.maxerror_us >= 0
    second = read_kernel_clock()
    assert second is not None and second.status == first.status  # reading changed nothing
    assert ctypes.sizeof(clocksync._Timex) >= 200  # the kernel's struct, reserved tail too
    assert clock_synced() is first.synced or clock_synced() is second.synced
