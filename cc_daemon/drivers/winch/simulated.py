"""The simulated winch: `LinePhysics` on the injected clock, for laptops and tests.

It keeps no timer running when idle; `wait_change` sleeps until the current
motion would end or a command changes the picture, whichever comes first. The
clock's `monotonic` must be the event loop's time base (`SystemClock` is).
"""

from __future__ import annotations

import asyncio
import contextlib

from cc_daemon.core.winch.physics import LinePhysics
from cc_daemon.core.winch.status import WinchStatus
from cc_daemon.ground.clock import Clock


class SimulatedWinch:
    def __init__(self, physics: LinePhysics, clock: Clock) -> None:
        self._physics = physics
        self._clock = clock
        self._changed = asyncio.Event()

    def status(self) -> WinchStatus:
        # Reading the status is what "observes" a change: a change that happens
        # after this read and before `wait_change` must wake that wait at once.
        self._changed.clear()
        return self._physics.status(self._clock.monotonic())

    def move_to(self, depth_m: float) -> None:
        self._physics.command(self._clock.monotonic(), depth_m)
        self._changed.set()

    def move_slowly_to(self, depth_m: float) -> None:
        """`move_to` at the approach speed (core.winch.status's ApproachSpeed): a blind
        cast pays out with the bed anywhere below."""
        self._physics.command(self._clock.monotonic(), depth_m, slow=True)
        self._changed.set()

    def move_at_most(self, depth_m: float, speed_m_s: float) -> None:
        """`move_to` no faster than `speed_m_s` and no slower than the approach speed
        (core.winch.status's LimitedSpeed): a profile's descent."""
        self._physics.command(self._clock.monotonic(), depth_m, max_speed_m_s=speed_m_s)
        self._changed.set()

    def stop(self) -> None:
        self._physics.stop(self._clock.monotonic())
        self._changed.set()

    async def wait_change(self, timeout: float) -> None:
        now = self._clock.monotonic()
        deadline = now + max(timeout, 0.0)
        arrival = self._physics.arrival_time(now)
        if arrival is not None:
            deadline = min(deadline, arrival)
        if self._changed.is_set() or deadline <= now:
            return
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(max(deadline - now, 0.0)):
                await self._changed.wait()

    async def close(self) -> None:
        self.stop()
