"""The one injectable clock.

Everything in the asyncio shell that waits or timestamps asks the same
`Clock`, so tests can substitute time and the depth report runs on absolute
deadlines. The sans-IO core never holds a clock: it is *given* `now`.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Protocol


class Clock(Protocol):
    def monotonic(self) -> float:
        """Seconds on a clock that never jumps (the basis of every deadline)."""
        ...

    def wall(self) -> float:
        """Seconds since the Unix epoch (may jump; recorded, never scheduled on)."""
        ...

    async def sleep_until(self, deadline: float) -> None:
        """Return once `monotonic()` has reached `deadline`."""
        ...


class SystemClock:
    """The real clock. asyncio's loop runs on `time.monotonic` too, so timers agree."""

    def monotonic(self) -> float:
        return time.monotonic()

    def wall(self) -> float:
        return time.time()

    async def sleep_until(self, deadline: float) -> None:
        delay = deadline - time.monotonic()
        await asyncio.sleep(delay if delay > 0 else 0)


async def sleep_until_or_set(
    clock: Clock, deadline: float, now: float, event: asyncio.Event
) -> None:
    """Sleep until `deadline` on `clock`, or until `event` is set, whichever is first:
    a duty asleep until its next deadline, woken when something brings one nearer.
    Never a busy loop, even on a deadline a rounding error keeps in the past."""
    sleeper = asyncio.ensure_future(clock.sleep_until(max(deadline, now + 0.001)))
    changed = asyncio.ensure_future(event.wait())
    try:
        await asyncio.wait((sleeper, changed), return_when=asyncio.FIRST_COMPLETED)
    finally:
        sleeper.cancel()
        changed.cancel()


async def run_on_deadlines(
    clock: Clock,
    changed: asyncio.Event,
    tick: Callable[[float], object],
    next_deadline: Callable[[float], float | None],
) -> None:
    """A duty's loop, for ever: `tick` what is due, then sleep until the next
    deadline, or until `changed` is set (something brought one nearer); with no
    deadline, until `changed` alone. Cleared after the tick, before the deadline is
    asked: a change the tick did not see wakes the next sleep at once."""
    while True:
        now = clock.monotonic()
        tick(now)
        changed.clear()
        deadline = next_deadline(now)
        if deadline is None:
            await changed.wait()
        else:
            await sleep_until_or_set(clock, deadline, now, changed)
