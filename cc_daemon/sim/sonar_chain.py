"""The simulated autopilot's sonar chain: its sonar module on a port, and a Ping1D behind it.

This module owns wiring the sonar into a simulated autopilot: a `SonarReader`
(the firmware's sonar module, over a supervised serial link at 115200 8N1) on
either a real port (`--sonar-port /dev/ttyUSB0`, a real Ping1D on the bench)
or a pty with the simulated Ping1D on its other end, hearing the mission's
water under the boat. The autopilot's `T` and `M` frames then carry what the
module last read.

It never touches the daemon, and it leaves the autopilot's made-up readings
alone when no sonar is attached.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from cc_daemon.drivers.sonar.reader import SonarReader
from cc_daemon.sim.autopilot import Autopilot, Phase
from cc_daemon.sim.mission import Point, SonarReading
from cc_daemon.sim.ping1d import FieldSounder, Ping1DDevice, Ping1DServer
from cc_daemon.sim.pty import PtyPair

OPEN_TIMEOUT_S = 5.0
# Three readings of the 250 ms stream: the M frame then carries what the sonar
# heard on station. A boat really does settle before sampling; at the
# simulator's brisk paces (80 m/s and more) a reading 250 ms old was taken tens
# of metres back, maybe off the shoal, or lost in the wake.
SETTLE_S = 0.75


class AutopilotSonar:
    """A running sonar chain. `close()` stops the stream, the reader and the device."""

    def __init__(
        self,
        reader: SonarReader,
        task: asyncio.Task[None],
        *,
        pair: PtyPair | None = None,
        server: Ping1DServer | None = None,
    ) -> None:
        self.reader = reader
        self.pair = pair
        self.server = server
        self._task = task

    @property
    def simulated(self) -> bool:
        return self.server is not None

    def reading(self) -> SonarReading:
        """What the autopilot's sonar module holds now, for a `T` or `M` frame."""
        current = self.reader.current()
        return SonarReading(current.distance_mm, current.confidence_pct)

    async def close(self) -> None:
        task = self._task
        if not task.done():
            task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        if self.server is not None:
            await self.server.close()
        if self.pair is not None:
            self.pair.close()


async def attach_sonar(
    autopilot: Autopilot,
    now: Callable[[], float],
    *,
    port: str | None,
    workdir: Path,
    seed: int = 1,
    max_age_s: float = 1.0,
) -> AutopilotSonar:
    """Start the chain and make `autopilot` read its sonar from it.

    `port` None: the simulated Ping1D on a pty in `workdir`. `now` is the
    autopilot's clock (the run's seconds), for the boat's position.
    """
    pair: PtyPair | None = None
    server: Ping1DServer | None = None
    if port is None:
        pair = PtyPair(workdir / "ttySONAR")

        def where() -> tuple[Point, bool]:
            return autopilot.position(now()), autopilot.phase is Phase.CRUISING

        sounder = FieldSounder(autopilot.mission, where, seed=seed)
        server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(sounder))
        port = str(pair.path)
    reader = SonarReader(port, max_age_s=max_age_s)
    task = asyncio.create_task(reader.run(), name="autopilot-sonar")
    chain = AutopilotSonar(reader, task, pair=pair, server=server)
    if server is not None:
        # The pty is there already: wait for the module to open it, so the
        # first frames carry a reading. A real port may come later.
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(OPEN_TIMEOUT_S):
                await reader.opened.wait()
    autopilot.sonar = chain.reading
    if autopilot.config.settle_s < SETTLE_S:
        autopilot.config = replace(autopilot.config, settle_s=SETTLE_S)
    return chain
