"""The daemon's own Ping1D (`[sonar]`): read it, journal it, offer its bottom to the planner.

This module owns the daemon side of an optional sonar wired to the companion
computer: a `SonarReader` built from the `[sonar]` settings, every reading
recorded in the journal (`record_sonar`), the port's openings and losses
recorded as events, and the start-measuring frame the planner should see
(`cast.bottom.station_for_plan`). The hub (`service.Daemon`) only starts
`run()` and asks `station_for_plan`.

It never decides a cast, never stops the daemon, and a journal failure never
stops the reading.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import structlog

from cc_daemon.config import SonarSettings
from cc_daemon.core.cast.bottom import ONBOARD, Sounding, station_for_plan
from cc_daemon.core.protocol import StartMeasuring
from cc_daemon.drivers.sonar.client import SonarReading
from cc_daemon.drivers.sonar.reader import SonarReader
from cc_daemon.ground.clock import Clock
from cc_daemon.store import Journal

_log = structlog.get_logger("cc_daemon.sonar")


class OnboardSonar:
    def __init__(
        self, settings: SonarSettings, clock: Clock, journal: Callable[[], Journal | None]
    ) -> None:
        if settings.port is None:
            raise ValueError("sonar.port is not set: no onboard sonar")
        self.settings = settings
        self._journal = journal
        self.reader = SonarReader(
            settings.port,
            baudrate=settings.baudrate,
            max_age_s=settings.max_age_s,
            restart_after_s=settings.restart_after_s,
            reconnect_initial_s=settings.reconnect_initial_s,
            reconnect_max_s=settings.reconnect_max_s,
            clock=clock,
            on_reading=self._record,
            on_state=self._on_state,
        )

    @property
    def port(self) -> str:
        return self.reader.port

    async def run(self) -> None:
        await self.reader.run()

    def station_for_plan(
        self, station: StartMeasuring, now: float, min_confidence: int
    ) -> StartMeasuring:
        """The frame the planner should see: with our bottom when it is the freshest usable."""
        latest = self.reader.client.latest
        onboard = Sounding(ONBOARD, latest.distance_mm, latest.confidence_pct, latest.at)
        chosen, source = station_for_plan(
            station,
            now,
            onboard,
            min_confidence=min_confidence,
            max_age_s=self.settings.max_age_s,
        )
        _log.info(
            "cast bottom chosen",
            source=source or "none usable",
            sonar_distance_mm=chosen.sonar_distance_mm,
            sonar_confidence_pct=chosen.sonar_confidence_pct,
            onboard_age_s=round(now - latest.at, 2) if math.isfinite(latest.at) else None,
        )
        return chosen

    def _record(self, reading: SonarReading) -> None:
        journal = self._journal()
        if journal is not None:
            journal.record_sonar(self.port, reading.distance_mm, reading.confidence_pct)

    def _on_state(self, up: bool, reason: str) -> None:
        journal = self._journal()
        if journal is None:
            return
        if up:
            journal.record_event("sonar_port_opened", port=self.port)
        else:
            journal.record_event("sonar_port_lost", port=self.port, reason=reason)
