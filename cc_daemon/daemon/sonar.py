"""The daemon's own Ping1D (`[sonar]`): read it, journal it, offer its bottom to the planner.

This module owns the daemon side of an optional sonar wired to the companion
computer: a `SonarReader` built from the `[sonar]` settings, every reading
recorded in the journal (`record_sonar`), the port's openings and losses
recorded as events, and the start-measuring frame the planner should see
(`cast.bottom.station_for_plan`). The hub (`service.Daemon`) only starts
`run()` and asks `station_for_plan`.

Readings are journaled at most `sonar.journal_rate_hz` a second (`SonarThinner`:
the first of each 1/rate interval kept, as it arrived, valid or not); the others
are counted with their least and greatest distance, a `sonar_thinning_started`
event is journaled when thinning starts and a `sonar_thinned` summary at most
every minute after, so a Ping streaming 1000 readings a second cannot fill the
disk and nothing is dropped unsaid.

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

REPORT_EVERY_S = 60.0  # at most one summary of thinned readings a minute


class SonarThinner:
    """Which readings to journal: at most `rate_hz` a second; a summary of the rest.

    Pure: readings (stamped with their arrival time) in, decisions and summaries
    out.
    """

    def __init__(self, rate_hz: float, report_every_s: float = REPORT_EVERY_S) -> None:
        self.rate_hz = rate_hz
        self.report_every_s = report_every_s
        self.thinning = False
        self.dropped = 0  # since the last summary
        self.dropped_total = 0
        self._invalid = 0
        self._min: int | None = None
        self._max: int | None = None
        self._slot: int | None = None
        self._since: float | None = None

    def keep(self, reading: SonarReading) -> bool:
        """Whether to journal `reading`; otherwise it is counted in the summary."""
        slot = math.floor(reading.at * self.rate_hz)
        if slot != self._slot:
            self._slot = slot
            return True
        if self._since is None:
            self._since = reading.at
        self.dropped += 1
        self.dropped_total += 1
        self._invalid += not reading.valid
        d = reading.distance_mm
        self._min = d if self._min is None else min(self._min, d)
        self._max = d if self._max is None else max(self._max, d)
        return False

    def starts(self) -> bool:
        """True once when readings begin to be dropped (after a quiet summary window)."""
        if self.dropped and not self.thinning:
            self.thinning = True
            return True
        return False

    def summary(self, now: float, *, everything: bool = False) -> dict[str, object] | None:
        """The summary due at `now` (at most every `report_every_s`), or None."""
        if self._since is None:
            return None
        if not everything and now - self._since < self.report_every_s:
            return None
        out: dict[str, object] = {
            "count": self.dropped,
            "invalid": self._invalid,
            "min_distance_mm": self._min,
            "max_distance_mm": self._max,
            "window_s": round(now - self._since, 3),
            "rate_hz": self.rate_hz,
        }
        self.dropped = self._invalid = 0
        self._min = self._max = None
        self._since = None
        self.thinning = False if everything else self.thinning
        return out

    def quiet(self) -> None:
        """No reading dropped for a whole window: the next drop starts thinning anew."""
        self.thinning = False


class OnboardSonar:
    def __init__(
        self, settings: SonarSettings, clock: Clock, journal: Callable[[], Journal | None]
    ) -> None:
        if settings.port is None:
            raise ValueError("sonar.port is not set: no onboard sonar")
        self.settings = settings
        self._journal = journal
        self.thinner = SonarThinner(settings.journal_rate_hz)
        self._last_summary_at: float | None = None
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
        try:
            await self.reader.run()
        finally:
            self._summarise(self.reader.client.latest.at, everything=True)

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
        if journal is None:
            return
        if self.thinner.keep(reading):
            # As it arrived: a reading that cannot be true is kept and flagged by
            # the rule every reader applies (`core.cast.bottom.sounding_valid`).
            journal.record_sonar(self.port, reading.distance_mm, reading.confidence_pct)
        elif self.thinner.starts():
            _log.warning(
                "sonar readings arrive faster than sonar.journal_rate_hz; journaling at "
                "that rate and summarising the rest",
                rate_hz=self.thinner.rate_hz,
            )
            journal.record_event(
                "sonar_thinning_started", port=self.port, rate_hz=self.thinner.rate_hz
            )
        self._summarise(reading.at)

    def _summarise(self, now: float, *, everything: bool = False) -> None:
        journal = self._journal()
        summary = self.thinner.summary(now, everything=everything)
        if summary is None:
            last = self._last_summary_at
            quiet_since = last is not None and now - last >= self.thinner.report_every_s
            if self.thinner.dropped == 0 and quiet_since:
                self.thinner.quiet()
            return
        self._last_summary_at = now
        if journal is not None:
            journal.record_event("sonar_thinned", port=self.port, **summary)

    def _on_state(self, up: bool, reason: str) -> None:
        journal = self._journal()
        if journal is None:
            return
        if up:
            journal.record_event("sonar_port_opened", port=self.port)
        else:
            journal.record_event("sonar_port_lost", port=self.port, reason=reason)
