"""A Ping1D on a serial port, read for as long as it takes: `SonarClient` over `SerialLink`.

This module owns the asyncio side of the sonar: it opens the port through
`SerialLink` (so a lost or late USB adapter is logged and the port reopened
with capped, jittered backoff, exactly as the autopilot's link), writes the
start sequence each time the port opens, restarts a stream gone silent, hands
every reading to `on_reading`, and writes `continuous_stop` before it closes.

It never decides what a reading means for a cast, and a callback's exception
never stops the reading.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable

import structlog

from cc_daemon.drivers.link import SerialLink
from cc_daemon.drivers.sonar.client import SonarClient, SonarReading
from cc_daemon.ground.clock import Clock, SystemClock

_log = structlog.get_logger("cc_daemon.sonar")

PING1D_BAUDRATE = 115200
_POLL_S = 0.25  # the stream's own period: a silent stream is noticed within one reading


class SonarReader:
    def __init__(
        self,
        port: str,
        *,
        baudrate: int = PING1D_BAUDRATE,
        max_age_s: float = 1.0,
        restart_after_s: float = 3.0,
        reconnect_initial_s: float = 0.2,
        reconnect_max_s: float = 5.0,
        clock: Clock | None = None,
        on_reading: Callable[[SonarReading], None] | None = None,
        on_state: Callable[[bool, str], None] | None = None,
    ) -> None:
        self._clock = clock or SystemClock()
        self.client = SonarClient(max_age_s=max_age_s, restart_after_s=restart_after_s)
        self.on_reading = on_reading
        self.on_state = on_state
        self.link = SerialLink(
            port,
            on_data=self._on_data,
            on_state=self._on_link_state,
            baudrate=baudrate,
            reconnect_initial_s=reconnect_initial_s,
            reconnect_max_s=reconnect_max_s,
        )
        self.opened = asyncio.Event()
        self.losses = 0

    @property
    def port(self) -> str:
        return self.link.port

    def current(self) -> SonarReading:
        """The latest reading, with confidence 0 once it is older than `max_age_s`."""
        return self.client.reading(self._clock.monotonic())

    async def run(self) -> None:
        """Read until cancelled; stop the stream on the way out."""
        link_task = asyncio.create_task(self.link.run(), name=f"sonar-link {self.port}")
        try:
            while True:
                await asyncio.sleep(_POLL_S)
                if self.link.up:
                    again = self.client.poll(self._clock.monotonic())
                    if again:
                        _log.warning("sonar silent: starting its stream again", port=self.port)
                        self.link.write(again)
        finally:
            if self.link.up:
                self.link.write(self.client.stop())
            link_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await link_task

    def _on_link_state(self, up: bool, reason: str) -> None:
        if up:
            self.link.write(self.client.start(self._clock.monotonic()))
            self.opened.set()
        else:
            self.losses += 1
        if self.on_state is not None:
            self.on_state(up, reason)

    def _on_data(self, data: bytes) -> None:
        for reading in self.client.feed(self._clock.monotonic(), data):
            if self.on_reading is None:
                continue
            try:
                self.on_reading(reading)
            except Exception:
                _log.exception("error handling a sonar reading")
