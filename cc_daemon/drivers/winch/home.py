"""Home, on the GPIO winch: the limit switch as the second witness of the count.

`HomeWitnessing` is the base of `gpio.GpioWinch`: the winch owns the motor, the
count and the threads; this owns what "home" means on it (docs/gpio-winch.md
"Home has two witnesses"): since when the switch has been closed, whether both
witnesses have agreed on home since, a disagreement that stands until they
agree again, the settle timer, start-up homing and the small drift corrected at
a verified home. The rules themselves are `core.winch.witness`'s.

Loop side only: gpiozero's thread never reaches this module. It must never
declare home on one witness, and never zero the count at a switch it does not
believe.
"""

from __future__ import annotations

import asyncio
import threading
from typing import TYPE_CHECKING, Any

import structlog

from cc_daemon.config import WinchGpioSettings
from cc_daemon.core.winch.drum import Drum
from cc_daemon.core.winch.silence import DepthEstimate
from cc_daemon.core.winch.status import HOMING_FAILED, WinchStatus
from cc_daemon.core.winch.witness import Witnesses
from cc_daemon.drivers.winch.devices import GpioDevices
from cc_daemon.drivers.winch.motor import Direction, HBridge
from cc_daemon.ground.clock import Clock

_log = structlog.get_logger("cc_daemon.winch.gpio")

WAIT_S = 0.2  # how often homing looks at the winch while it waits
SWITCH_SETTLE_S = 0.1  # a switch that opens by itself must stay open this long to be news


class HomeWitnessing:
    """Home on two witnesses (see the module docstring). Its state is set up by
    `GpioWinch.__init__`."""

    _cfg: WinchGpioSettings
    _dev: GpioDevices
    _bridge: HBridge
    _clock: Clock
    _loop: asyncio.AbstractEventLoop
    _changed: asyncio.Event
    _lock: threading.Lock
    _count: int
    _last_step: int
    _count_known: bool
    _switch_now: bool
    _encoder_bad: str | None
    _estimate: DepthEstimate | None
    _ignored: int
    _ignored_told: int
    _witnesses: Witnesses
    drum: Drum
    _fault: str | None
    _homed: bool
    _started_at: float
    _closed_since: float | None
    _verified: bool
    _distrust: str | None
    _settle: asyncio.TimerHandle | None
    _haul_witnessed: bool

    if TYPE_CHECKING:

        @property
        def line_m(self) -> float: ...

        def status(self) -> WinchStatus: ...

        async def wait_change(self, timeout: float) -> None: ...

        def _begin(self, target_m: float, *, homing: bool = False, pace: float = 1.0) -> None: ...

        def _halt(self) -> None: ...

        def _fail(self, fault: str, **detail: Any) -> None: ...

        def _record(self, kind: str, **detail: Any) -> None: ...

    @property
    def at_home(self) -> bool:
        """Home verified by both witnesses (the count near zero, the switch settled closed)."""
        return (
            self._verified
            and self._distrust is None
            and self.switch_closed
            and abs(self.line_m) <= self._cfg.count_tolerance_m
        )

    @property
    def switch_closed(self) -> bool:
        """The limit switch alone, as the pin says now (one witness, not home)."""
        return bool(self._dev.switch.is_active)

    @property
    def distrust(self) -> str | None:
        """The witnesses' disagreement standing, if any."""
        return self._distrust

    @property
    def homed(self) -> bool:
        return self._homed

    async def start_up(self, left_down_m: float | None = None) -> None:
        """Make sure the probe is home before casts are accepted (READY comes after).

        `left_down_m`: the journal's last depth of a cast the previous run died in.
        A fresh process has no count, so a switch closed at start would be home on
        one witness; from that depth only a haul, counted or run, may bring the
        probe home (a shorted switch must not release the station with R-F)."""
        if left_down_m is not None and left_down_m > self._cfg.count_tolerance_m:
            self._estimate = DepthEstimate(
                left_down_m, left_down_m, left_down_m, self.line_m, reckoned=False
            )
            _log.warning(
                "the previous run died with the probe down: home needs a haul from there",
                left_down_m=round(left_down_m, 3),
                switch_closed=self.switch_closed,
            )
            self._record("winch_left_down", left_down_m=round(left_down_m, 3))
        if self.switch_closed:
            if self._settle is None and not self._verified:  # its edge not yet handed over
                self._closed_since = self._closed_since or self._clock.monotonic()
                self._schedule_settle(self._closed_since)
            await self._settled_or_moved()
            if self.at_home:
                _log.info("winch at home: limit switch closed at start")
                return
        if not self._cfg.home_at_start:
            self._fault = (
                "not homed: the limit switch was open at start and home_at_start is false; "
                "casts are refused until the probe is homed (by hand or `cc-daemon winch home`)"
            )
            _log.error("winch not homed: casts refused", reason=self._fault)
            self._record("winch_fault", fault=self._fault)
            return
        await self.home(reason="limit switch open at start: the probe may be down")

    async def home(self, *, reason: str = "operator request") -> bool:
        """Haul in until the limit switch closes; True once home. The count means
        nothing until then (the probe was moved, or the power cut)."""
        # Its own clock: with the switch already closed no motion starts, and the
        # motion's start time would be stale (or 0: the machine's uptime).
        started = self._clock.monotonic()
        with self._lock:
            # Closed now, the switch is the only witness there is: it sets the count.
            closed = self._count_known = self._switch_now
            if closed:
                self._count, self._last_step = 0, 1
        self._haul_witnessed = True  # an explicit homing: the switch may set home
        if closed:
            _log.info("winch homing: the limit switch is already closed; letting it settle")
        else:
            _log.warning("winch homing: hauling in until the limit switch closes", reason=reason)
        self._record("winch_homing", reason=reason, counted_line_m=round(self.line_m, 3))
        self._begin(0.0, homing=True)
        await self._settled_or_moved()
        if self.at_home:
            self._homed = True
            _log.info("winch homed", took_s=round(self._clock.monotonic() - started, 2))
            self._record("winch_homed", reason=reason)
            return True
        # Main's rules read this prefix (core.winch.status): a winch whose homing
        # failed vouches for no home and starts no cast until it is homed again.
        self._fault = f"{HOMING_FAILED}: {self._fault or 'the probe is not home'}"
        _log.critical("winch homing failed: the probe is not home", fault=self._fault)
        self._record("winch_fault", fault=self._fault)
        return False

    async def _settled_or_moved(self) -> None:
        """Wait until the motor is off and the switch has settled (or opened)."""
        while self.status().moving:
            await self.wait_change(WAIT_S)

    def _switch_seen(self, closed: bool, running: Direction) -> None:
        if not closed:
            self._closed_since = None
            self._verified = False
            self._haul_witnessed = False
            self._cancel_settle()
            if running is Direction.STOPPED and self._homed:
                self._loop.call_later(SWITCH_SETTLE_S, self._opened_while_stopped)
            self._changed.set()
            return
        now = self._clock.monotonic()
        self._closed_since = now
        self._haul_witnessed = self._haul_witnessed or running is Direction.HAUL_IN
        if not self._count_known:
            # Homing from an unknown position: the switch is the only witness
            # there is, and it sets the count (still settled before home).
            with self._lock:
                self._count, self._last_step, self._count_known = 0, 1, True
            _log.info("winch count set at the switch after homing from an unknown position")
        line = self.line_m
        if running is Direction.PAY_OUT:
            reason: str | None = (
                f"witnesses disagree: the limit switch closed while paying out with "
                f"{line:.2f} m counted (a snag, a bouncing lever or a wiring fault)"
            )
        else:
            reason = self._witnesses.disagreement(line, True, 0)
        if reason is not None:
            self._distrusted(reason)
            return
        if running is Direction.HAUL_IN:
            self._halt()
            _log.info("winch at the limit switch: settling", counted_line_m=round(line, 3))
        self._schedule_settle(now)

    def _schedule_settle(self, since: float) -> None:
        """Home is verified once the switch has stayed closed `switch_settle_s` from `since`."""
        self._cancel_settle()
        delay = max(0.0, since + self._cfg.switch_settle_s - self._clock.monotonic())
        self._settle = self._loop.call_later(delay, self._settled, since)
        self._changed.set()

    def _cancel_settle(self) -> None:
        if self._settle is not None:
            self._settle.cancel()
            self._settle = None

    def _settled(self, since: float) -> None:
        self._settle = None
        self._changed.set()
        if self._closed_since != since or not self.switch_closed:
            return  # it opened again: a blip, not home
        reason = self._witnesses.disagreement(self.line_m, True, 0)
        with self._lock:
            bad = self._encoder_bad
        if reason is None and bad is not None and not self._haul_witnessed:
            # The count is not a witness (an encoder fault): a switch that closed with
            # nothing hauling in (a short, a snag on the lever) would be home on one
            # witness alone. Only a haul in that ends at the switch may say so.
            reason = (
                "the limit switch closed with no haul running while the count is not "
                "trusted (an encoder fault): one witness cannot verify home"
            )
        estimate = self._estimate
        if reason is None and estimate is not None and estimate.low_m > self._cfg.count_tolerance_m:
            # The depth estimate says the probe cannot be home: the switch is wrong.
            reason = (
                f"the limit switch closed where the probe cannot be home: {estimate.describe()}"
            )
        if reason is not None:
            self._distrusted(reason)
            return
        line = self.line_m
        self._zero_at_switch()
        self._estimate = None  # both witnesses say home: no doubt left about the depth
        self._verified = True
        self._homed = True
        _log.info("winch home: limit switch closed", counted_line_m=round(line, 3))
        if self._distrust is not None:
            with self._lock:  # an encoder fault too: the count is trusted again from zero
                self._encoder_bad, self._ignored = None, 0
            self._ignored_told = 0
            _log.warning("winch home verified: both witnesses agree again", was=self._distrust)
            self._record("winch_home_verified", was=self._distrust)
            self._distrust = None
            self._fault = None

    def _distrusted(self, reason: str, **detail: Any) -> None:
        """The count and the switch contradict each other: motor off, no home until
        both agree again (an operator's haul), the fault journaled with both figures."""
        self._cancel_settle()
        self._verified = False
        self._distrust = reason
        self._fail(
            reason,
            counted_line_m=round(self.line_m, 3),
            switch_closed=self.switch_closed,
            **detail,
        )

    def _opened_while_stopped(self) -> None:
        if self.switch_closed or self._bridge.direction is not Direction.STOPPED:
            return  # a bounce, or a motion began
        # Nobody is paying out, yet the probe left the block: it slipped, or someone
        # pulled it. The next station brings it home first (a recovery cast).
        _log.warning(
            "winch count and limit switch disagree: the switch opened with the motor stopped",
            counted_line_m=round(self.line_m, 3),
            switch="open",
        )

    def _zero_at_switch(self) -> None:
        """Both witnesses agree on home: correct a small drift of the count, saying so."""
        with self._lock:
            count = self._count  # at the switch the line is in [0, 1) pulses: count 0
            self._count = 0
            self._last_step = 1
        if count == 0:
            return
        line = self.drum.line_m(count)
        _log.info(
            "winch count corrected at a verified home",
            counted_line_m=round(line, 3),
            switch="closed",
            tolerance_m=self._cfg.count_tolerance_m,
        )
        self._record(
            "winch_count_corrected",
            counted_line_m=round(line, 3),
            pulses=count,
            corrected_to_m=0.0,
        )
