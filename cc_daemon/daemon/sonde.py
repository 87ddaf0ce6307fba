"""The sonde's duty in the daemon: sample on a steady beat, journal, watch the depth.

This module owns the sampling task the daemon starts beside its serial link:
one reading every `sonde.period_s` on absolute deadlines while a cast runs and
every `sonde.idle_period_s` at the surface (a cast starting mid-wait is sampled
at once and sets a new beat); each reading journaled with the cast, its phase,
the line out when the request went out and every value; the depth monitor fed
and its events logged, journaled and, for a bottom contact, handed to the
daemon; the freshest sonde depth kept for `cast.depth_source = "sonde"`. With
`sonde.backend = "sim"` it also runs the simulated sonde on a private pty.

It never commands the winch (the daemon's `bottom_contact` does, through the
cast machine), and never lets a cast wait for the sonde: the daemon reads
`report_depth`, a plain attribute lookup.
"""

from __future__ import annotations

import asyncio
import bisect
import contextlib
import math
import tempfile
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import structlog

from cc_daemon.config import Settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.daemon.simulators import SondeSimulatorFactory
from cc_daemon.ground.clock import Clock
from cc_daemon.store import Journal

if TYPE_CHECKING:  # the sonde's modules (and pyserial) are imported only for a sonde
    from cc_daemon.drivers.sonde.depthcheck import (
        BottomContact,
        DepthAgreement,
        DepthDisagreement,
    )
    from cc_daemon.drivers.sonde.reader import SondeReader, SondeReading

_log = structlog.get_logger("cc_daemon.sonde")

SURFACE = "surface"  # the phase recorded for readings taken with no cast running
# A line out growing by more than this between two readings is "paying out".
_PAYING_OUT_M = 0.01
# Readings remembered for late replies: the reader owes none older than
# `reader.LATE_LIMIT_S` (30 s), 300 readings at the shortest period.
_ASKED_KEPT = 300


class DaemonView(Protocol):
    """What the duty reads of the daemon (satisfied by `service.DaemonStatus`)."""

    @property
    def phase(self) -> str: ...
    @property
    def cast_id(self) -> int | None: ...
    @property
    def probe_depth_m(self) -> float: ...


class SondeDuty:
    def __init__(
        self,
        settings: Settings,
        *,
        clock: Clock,
        journal: Journal | None,
        view: Callable[[], DaemonView],
        on_bottom_contact: Callable[[float], None],
        reader: SondeReader | None = None,
        simulator: SondeSimulatorFactory | None = None,
    ) -> None:
        """`simulator` builds the simulated sonde behind `sonde.backend = "sim"`."""
        self.settings = settings
        sonde = settings.sonde
        self._clock = clock
        self._journal = journal
        self._view = view
        self._on_bottom_contact = on_bottom_contact
        self._simulated = sonde.backend == "sim"
        if self._simulated and simulator is None and reader is None:
            raise ConfigError(
                'sonde.backend = "sim" needs the simulated sonde, which only the simulator '
                "and the cc-daemon command provide"
            )
        self._make_simulator = simulator
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if reader is None:
            from cc_daemon.drivers.sonde.reader import SondeReader

            if self._simulated:
                self._tmp = tempfile.TemporaryDirectory(prefix="cc-daemon-sonde-")
                sonde = sonde.model_copy(update={"port": str(Path(self._tmp.name) / "ttySONDE")})
            reader = SondeReader(sonde, monotonic=clock.monotonic, wall=clock.wall)
        self.reader = reader
        from cc_daemon.drivers.sonde.depthcheck import DepthMonitor

        self.monitor = DepthMonitor(
            disagreement_m=sonde.depth_disagreement_m,
            contact_s=sonde.bottom_contact_s,
            tolerance_m=sonde.bottom_contact_tolerance_m,
        )
        self.samples = 0
        self.latest: SondeReading | None = None
        self._latest_depth: tuple[float, float] | None = None  # (mono_s, metres)
        self._line_out_m = 0.0
        self._last_cast: int | None = None
        self._was_up: bool | None = None
        # (mono_s, cast_id, phase, line out) of recent readings: a late reply is
        # journaled with the cast, phase and line out of the time it was asked.
        self._asked: deque[tuple[float, int | None, str, float]] = deque(maxlen=_ASKED_KEPT)

    # ------------------------------------------------------------ for the daemon

    def report_depth(self, winch_depth_m: float, now: float) -> float:
        """The depth R-M reports: the winch's, or a fresh sonde depth if so configured."""
        if self.settings.cast.depth_source != "sonde" or self._latest_depth is None:
            return winch_depth_m
        at, depth = self._latest_depth
        if now - at > self.settings.sonde.stale_s:
            return winch_depth_m
        return max(depth, 0.0)

    # ------------------------------------------------------------ the task

    async def run(self) -> None:
        simulator = None
        try:
            if self._simulated and self._make_simulator is not None:
                simulator = self._make_simulator(
                    Path(self.reader.settings.port), lambda: self._line_out_m, self.settings
                )
                await asyncio.to_thread(simulator.start)
                _log.info("simulated sonde started", port=str(simulator.path))
            # The map travels with the data: exports label units from the journal alone.
            self._event(
                "sonde_started",
                backend=self.settings.sonde.backend,
                port=self.reader.settings.port,
                slave_id=self.settings.sonde.slave_id,
                depth_parameter=self.settings.sonde.depth_parameter,
                parameters=[
                    p.model_dump(by_alias=True, mode="json") for p in self.settings.sonde.parameters
                ],
            )
            await self._sample_forever()
        finally:
            await self.reader.close()
            if simulator is not None:
                await asyncio.to_thread(simulator.stop)
            if self._tmp is not None:
                self._tmp.cleanup()

    async def _sample_forever(self) -> None:
        sonde = self.settings.sonde
        next_at = self._clock.monotonic()
        while True:
            await self._wait_for(next_at)
            view = self._view()
            now = self._clock.monotonic()
            if view.cast_id is not None and view.cast_id != self._last_cast:
                next_at = now  # a new cast: its beat starts with its first reading
            await self.sample(view)
            period = sonde.period_s if view.cast_id is not None else sonde.idle_period_s
            next_at += period
            now = self._clock.monotonic()
            if next_at <= now:  # late (a stalled loop): skip the missed beats, no burst
                next_at += math.ceil((now - next_at) / period) * period

    async def _wait_for(self, deadline: float) -> None:
        """Sleep until `deadline`, waking early if a cast starts while at the surface."""
        step = self.settings.sonde.period_s / 4
        while True:
            now = self._clock.monotonic()
            if now >= deadline:
                return
            cast_id = self._view().cast_id
            if cast_id is not None and cast_id != self._last_cast:
                return
            await self._clock.sleep_until(min(deadline, now + step))

    async def sample(self, view: DaemonView) -> SondeReading:
        """One reading, journaled and checked against the winch."""
        cast_id = view.cast_id
        if cast_id != self._last_cast:
            self.monitor.reset()
        previous_line = self._line_out_m
        self._line_out_m = line_out = view.probe_depth_m
        reading = await self.reader.read()
        self.samples += 1
        self.latest = reading
        depth = reading.value(self.settings.sonde.depth_parameter)
        if depth is not None:
            self._latest_depth = (reading.mono_s, depth)
        phase = view.phase if cast_id is not None else SURFACE
        self._asked.append((reading.mono_s, cast_id, phase, line_out))
        self._record(reading, cast_id, phase, line_out)
        for late in reading.late:
            # Flagged `late`, with the time, cast and line out it was asked at;
            # never fed to the depth monitor nor used for R-M.
            self._record(late, *self._context(late.mono_s))
        self._link_events()
        paying_out = (
            cast_id is not None
            and cast_id == self._last_cast
            and view.phase == "descending"
            and line_out > previous_line + _PAYING_OUT_M
        )
        self._last_cast = cast_id
        for event in self.monitor.feed(reading.mono_s, line_out, depth, paying_out=paying_out):
            self._depth_event(event, cast_id)
        return reading

    def _context(self, mono_s: float) -> tuple[int | None, str, float | None]:
        """The cast, phase and line out of the reading during which `mono_s` fell."""
        k = bisect.bisect_right([a[0] for a in self._asked], mono_s + 1e-9) - 1
        if k < 0:
            return None, SURFACE, None
        _, cast_id, phase, line_out = self._asked[k]
        return cast_id, phase, line_out

    def _record(
        self, reading: SondeReading, cast_id: int | None, phase: str, line_out: float | None
    ) -> None:
        if self._journal is None:
            return
        self._journal.record_sonde_sample(
            cast_id=cast_id,
            phase=phase,
            mono_s=reading.mono_s,
            wall_s=reading.wall_s,
            duration_s=reading.duration_s,
            status=reading.status,
            error=reading.error,
            line_out_m=line_out,
            sonde_depth_m=reading.value(self.settings.sonde.depth_parameter),
            values=reading.values,
            missing=reading.missing,
            simulated=self._simulated,
        )

    def _link_events(self) -> None:
        up = self.reader.up
        if up == self._was_up:
            return
        if up:
            self._event("sonde_port_opened", port=self.reader.settings.port)
        elif self._was_up is not None or self.reader.last_reason:
            self._event(
                "sonde_port_lost", port=self.reader.settings.port, reason=self.reader.last_reason
            )
        self._was_up = up

    def _depth_event(
        self, event: DepthDisagreement | DepthAgreement | BottomContact, cast_id: int | None
    ) -> None:
        from cc_daemon.drivers.sonde.depthcheck import (
            BottomContact,
            DepthAgreement,
            DepthDisagreement,
        )

        match event:
            case DepthDisagreement(line_out_m=line, sonde_depth_m=depth):
                _log.warning(
                    "sonde depth and line out disagree (slanted line, or on the bottom?)",
                    cast_id=cast_id,
                    line_out_m=round(line, 3),
                    sonde_depth_m=round(depth, 3),
                    threshold_m=self.settings.sonde.depth_disagreement_m,
                )
                self._event("sonde_depth_disagreement", cast_id=cast_id, line_out_m=line,
                            sonde_depth_m=depth)  # fmt: skip
            case DepthAgreement(line_out_m=line, sonde_depth_m=depth):
                _log.info("sonde depth and line out agree again", cast_id=cast_id)
                self._event("sonde_depth_agreement", cast_id=cast_id, line_out_m=line,
                            sonde_depth_m=depth)  # fmt: skip
            case BottomContact(sonde_depth_m=depth, line_out_m=line, still_for_s=still):
                _log.warning(
                    "bottom contact: the sonde stopped going down while the line went out; "
                    "stopping the descent here",
                    cast_id=cast_id,
                    sonde_depth_m=round(depth, 3),
                    line_out_m=round(line, 3),
                )
                self._event("bottom_contact", cast_id=cast_id, sonde_depth_m=depth,
                            line_out_m=line, still_for_s=still)  # fmt: skip
                self._on_bottom_contact(depth)

    def _event(self, kind: str, **detail: object) -> None:
        if self._journal is not None:
            with contextlib.suppress(Exception):  # the journal logs its own failures
                self._journal.record_event(kind, **detail)


def make_sonde(
    settings: Settings,
    *,
    clock: Clock,
    journal: Journal | None,
    view: Callable[[], DaemonView],
    on_bottom_contact: Callable[[float], None],
    simulator: SondeSimulatorFactory | None = None,
) -> SondeDuty | None:
    """The configured sonde's duty, or None for `sonde.backend = "none"`."""
    if settings.sonde.backend == "none":
        return None
    return SondeDuty(
        settings,
        clock=clock,
        journal=journal,
        view=view,
        on_bottom_contact=on_bottom_contact,
        simulator=simulator,
    )
