"""Waiting on the event a test checks, never on a sleep's length.

`until` (in a coroutine) and `until_sync` poll a condition and return its value
as soon as it is true. The deadline only bounds how long a failing test takes
to say so: it is generous (`DEADLINE_S`) because a loaded machine may take many
times the idle time (a daemon subprocess answered its first S after 7.5 s, at
worst 13 s, on 2 cores beside three CPU hogs and other suites, load average 25;
0.5 s idle), and a passing test never waits for it.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import TypeVar

from cc_daemon.core.protocol import ProbePosition, ProbePositionRequest
from tests.daemonkit import DaemonProcess

T = TypeVar("T")

DEADLINE_S = 60.0


async def until(
    check: Callable[[], T], what: str = "the condition", timeout: float = DEADLINE_S
) -> T:
    """`check()`'s value once it is true-ish, polled every 10 ms without blocking
    the loop; AssertionError naming `what` after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while not (found := check()):
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout:g} s: {what}")
        await asyncio.sleep(0.01)
    return found


def until_sync(
    check: Callable[[], T],
    what: str = "the condition",
    timeout: float = DEADLINE_S,
    every: float = 0.01,
) -> T:
    """`until` for a test without an event loop: it blocks, polling every `every` s."""
    deadline = time.monotonic() + timeout
    while not (found := check()):
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout:g} s: {what}")
        time.sleep(every)
    return found


async def until_probe_down(daemon: DaemonProcess, depth_mm: int) -> int:
    """Ask S until the daemon's R-P puts the probe `depth_mm` or more down; that depth.
    Where a cast is by the daemon's own word, not after a guessed time: at 1 m/s, 2 m
    down is 2 s or more after the P-M however loaded the machine, and the rest of
    the cast is the margin for what the test does next while it runs."""
    assert daemon.port is not None
    deadline = time.monotonic() + DEADLINE_S
    while time.monotonic() < deadline:
        await daemon.port.send(ProbePositionRequest(1))
        reply = await daemon.expect(ProbePosition, DEADLINE_S)
        depth: int = reply.message.depth_mm  # type: ignore[union-attr]
        if depth >= depth_mm:
            return depth
        await asyncio.sleep(0.02)
    raise AssertionError(f"the probe never reached {depth_mm} mm:\n{daemon.log_text()[-3000:]}")
