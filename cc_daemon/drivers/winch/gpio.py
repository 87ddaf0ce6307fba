"""The real winch on the Pi's GPIO, behind the `Winch` interface.

It owns one motion at a time: the motor through an H-bridge, the line counted
from drum pulses (revolutions x circumference is the probe's depth), the home
limit switch, the optional motor current, and every safety rule of
docs/gpio-winch.md.

Threads. gpiozero calls the pulse and switch callbacks on its own thread (its
base `edges.EdgeCounting`), and the loop watchdog runs on another. On those
threads the only thing done to the motor is *stopping* it (at the target count,
at the end of the line, at the switch, where the witnesses disagree), under the
H-bridge's lock; everything else is handed to the event loop with
`call_soon_threadsafe`. What "home" means (two witnesses: the count and the
switch) is its base `home.HomeWitnessing`'s; whether the count can be believed
(an encoder fault) is `trust.CountTrust`'s. Starting the motor, the ramp, the
safety checks, logging and journaling happen on the loop only.

It must never leave the motor running: `stop`, `close`, an exception in a
tick, the loop going quiet (watchdog thread) and interpreter exit (atexit)
all switch it off.
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import functools
import math
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import structlog

from cc_daemon.config import WinchGpioSettings
from cc_daemon.core.errors import WinchFault
from cc_daemon.core.winch.drum import Drum
from cc_daemon.core.winch.encoder import EncoderJudge, coast_allowance, max_pulse_rate
from cc_daemon.core.winch.safety import Limits, MotionGuard
from cc_daemon.core.winch.silence import DepthEstimate
from cc_daemon.core.winch.status import APPROACH_FRACTION, WinchStatus
from cc_daemon.core.winch.witness import LEAVE_PULSES, Witnesses
from cc_daemon.drivers.winch.devices import GpioDevices
from cc_daemon.drivers.winch.edges import EdgeCounting, Goal
from cc_daemon.drivers.winch.home import HomeWitnessing
from cc_daemon.drivers.winch.motor import Direction
from cc_daemon.drivers.winch.sensing import ZERO_SETTLE_S, MotorSensing
from cc_daemon.drivers.winch.trust import CountTrust
from cc_daemon.drivers.winch.watchdog import LoopWatchdog
from cc_daemon.ground.clock import Clock

_log = structlog.get_logger("cc_daemon.winch.gpio")

# The interpreter's thread switch interval while the winch is open: gpiozero's
# callback thread (a pulse storm on a broken wire) may otherwise hold the GIL for
# the default 5 ms each time, and the loop answers the autopilot late
# (docs/performance.md). Restored at close.
GIL_SWITCH_S = 0.0005
TICK_S = 0.05  # safety checks, ramp steps and watchdog feeding while the motor runs
RAMP_FLOOR = 0.3  # the soft start begins at this fraction of the duty

EventSink = Callable[..., None]  # (kind, **detail): the journal's record_event


class GpioWinch(EdgeCounting, CountTrust, HomeWitnessing):
    def __init__(
        self,
        cfg: WinchGpioSettings,
        devices: GpioDevices,
        *,
        max_line_m: float,
        clock: Clock,
        record: EventSink | None = None,
        on_close: Callable[[], None] | None = None,
    ) -> None:
        self._cfg = cfg
        self._on_close = on_close
        self._dev = devices
        self._bridge = devices.bridge
        self._clock = clock
        self._record_sink = record
        self._loop = asyncio.get_running_loop()
        self.drum = Drum(cfg.pulses_per_rev, cfg.drum_diameter_m)
        self.max_line_m = max_line_m
        # Rounded down: the last pulse allowed is never past the end of the line.
        self._max_count = math.floor(max_line_m / self.drum.metres_per_pulse + 1e-9)
        self._sensing = MotorSensing(cfg, devices, self._record)
        self._limits = Limits(cfg.stall_timeout_s, cfg.max_current_a, cfg.overcurrent_s)
        self._witnesses = Witnesses(
            cfg.count_tolerance_m, cfg.switch_settle_s, LEAVE_PULSES * self.drum.metres_per_pulse
        )
        self._changed = asyncio.Event()
        # Shared with gpiozero's thread, under _lock.
        self._lock = threading.Lock()
        # The drum's position as the index of the mark last passed going out: line
        # in [count, count + 1) pulses. A mark passed going in leaves the line at
        # count + 1 pulses, so the line at the last edge depends on its direction.
        self._count = 0
        self._last_step = 1
        # False until the switch has set it (start-up with it open, homing from an
        # unknown position): a count that means nothing witnesses nothing.
        self._count_known = bool(devices.switch.is_active)
        self._goal: Goal | None = None
        self._target_count = 0
        self._last_direction = Direction.PAY_OUT  # a lone pulse with no command: line going out
        self._switch_now = bool(devices.switch.is_active)  # as the last edge left it
        mpp = self.drum.metres_per_pulse
        self._encoder = EncoderJudge(
            max_pulses_s=max_pulse_rate(
                cfg.line_speed_m_s, min(cfg.payout_duty, cfg.haulin_duty), mpp
            ),
            coast_pulses=coast_allowance(cfg.count_tolerance_m, mpp),
        )
        self._encoder_bad: str | None = None  # pulses that cannot be true: not counted
        self._estimate: DepthEstimate | None = None  # where the probe is, the count in doubt
        self._ignored = 0  # pulses not counted since the encoder fault
        self._stops_in_flight = 0  # motor stops made on a thread, not yet heard on the loop
        self._motion = 0  # which motion a stop made on a thread ended (see `_pulse_seen`)
        # Loop side only.
        self._fault: str | None = None
        self._homed = False
        # The second witness: since when the switch has been closed, whether both
        # witnesses have agreed on home since, and a disagreement standing until
        # they agree again (docs/gpio-winch.md "Home has two witnesses").
        self._closed_since: float | None = None
        self._verified = False
        self._distrust: str | None = None
        self._settle: asyncio.TimerHandle | None = None
        # With the count not trusted, only a switch closed by a haul in (an operator's:
        # nothing else moves then) or an explicit homing may verify home (home.py).
        self._haul_witnessed = False
        self._pending: asyncio.TimerHandle | None = None  # a start waiting for the zero
        self._ignored_told = 0
        self._summary: asyncio.TimerHandle | None = None
        self._guard: MotionGuard | None = None
        self._started_at = 0.0
        self._duty = 0.0
        self._approach_duty = 0.0
        self._tick: asyncio.TimerHandle | None = None
        self._arrived_count: int | None = None  # where an arrival stop left the count
        self._told_open_at_zero = False
        self._closed = False
        self.overshoots: list[int] = []  # pulses past the target after each arrival
        self._watchdog = LoopWatchdog(cfg.loop_watchdog_s, self._watchdog_trip)
        self._switch_interval = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch_interval, GIL_SWITCH_S))
        atexit.register(self._emergency_stop)
        devices.switch.when_activated = self._switch_closed_thread
        devices.switch.when_deactivated = self._switch_opened_thread
        if devices.pulses is not None:
            devices.pulses.when_activated = self._pulse_thread
        if devices.encoder is not None:
            devices.encoder.when_rotated_clockwise = self._step_out_thread
            devices.encoder.when_rotated_counter_clockwise = self._step_in_thread
        if self._switch_now:
            self._closed_since = clock.monotonic()
            self._schedule_settle(self._closed_since)

    # ------------------------------------------------------------ the Winch interface

    def status(self) -> WinchStatus:
        self._changed.clear()
        running = self._bridge.direction is not Direction.STOPPED
        estimate = self.depth_estimate
        return WinchStatus(
            depth_m=self.depth_m,  # the count's, or the best estimate when it is in doubt
            # Settling at the switch is still arriving: home is not yet verified.
            # So is a stop made on gpiozero's thread that the loop has not heard yet.
            moving=running
            or self._settle is not None
            or self._pending is not None
            or self._stops_in_flight > 0,
            at_home=self.at_home,
            # A standing disagreement is the fault, except while an operator's
            # hand haul runs (it must not stop the haul that can clear it).
            fault=self._fault or (self._distrust if not running else None),
            sensor_fault=self._sensing.fault,
            depth_low_m=estimate.low_m if estimate is not None else None,
            depth_high_m=estimate.high_m if estimate is not None else None,
        )

    def move_to(self, depth_m: float, *, slow: bool = False, pace: float = 1.0) -> None:
        """Run to `depth_m` at `pace` of the nominal duty (the approach duty if `slow`)."""
        if self._closed:
            raise WinchFault("the GPIO winch is closed")
        if self._distrust is not None:
            raise WinchFault(
                f"{self._distrust}; the winch moves only by hand (P-U, `cc-daemon winch`) "
                "until both witnesses agree on home"
            )
        if not self._homed:
            raise WinchFault(
                "winch not homed: the limit switch has not closed since start-up; "
                "haul the probe up by hand or run `cc-daemon winch home`"
            )
        pace = APPROACH_FRACTION if slow else min(max(pace, APPROACH_FRACTION), 1.0)
        self._begin(min(max(depth_m, 0.0), self.max_line_m), pace=pace)

    def move_slowly_to(self, depth_m: float) -> None:
        """`move_to` at the approach duty for the whole motion (core.winch.status's
        ApproachSpeed): a blind cast pays out with the bed anywhere below."""
        self.move_to(depth_m, slow=True)

    def move_at_most(self, depth_m: float, speed_m_s: float) -> None:
        """`move_to` no faster than `speed_m_s`, and no slower than the approach duty
        (core.winch.status's LimitedSpeed): the duty scaled as line_speed_m_s is."""
        self.move_to(depth_m, pace=speed_m_s / self._cfg.line_speed_m_s)

    def stop(self) -> None:
        self._halt()
        self._changed.set()

    async def wait_change(self, timeout: float) -> None:
        if self._changed.is_set() or timeout <= 0:
            return
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout):
                await self._changed.wait()

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._halt()
        finally:
            if self._summary is not None:
                self._summary.cancel()
            self._watchdog.close()
            sys.setswitchinterval(self._switch_interval)
            atexit.unregister(self._emergency_stop)
            try:
                # What drives the pins (the simulated drum) stops before they close:
                # gpiozero clears a device's callbacks on close, and an edge still
                # arriving then calls the None it finds (seen in CI under a pulse storm).
                if self._on_close is not None:
                    self._on_close()
            finally:
                self._dev.close()

    # ------------------------------------------------------------ more than a Winch

    @property
    def line_m(self) -> float:
        with self._lock:
            return self.drum.line_m(self._edge())

    @property
    def pulse_count(self) -> int:
        with self._lock:
            return self._count

    def motor_current_a(self) -> float | None:
        """The current sensor's reading as it is (trusted or not: see `sensor_fault`)."""
        return self._sensing.raw_current_a()

    @property
    def sensor_fault(self) -> str | None:
        """The current sensor's fault, once found (overcurrent then by pulses alone)."""
        return self._sensing.fault

    def supply_v(self) -> float | None:
        return self._sensing.supply_v()

    def hand_move(self, depth_m: float) -> None:
        """An operator's move (the RC stick): like `jog`, allowed while the witnesses
        disagree, since an operator's haul home is what can make them agree again."""
        line = self.depth_m
        if depth_m <= 0.0:
            self.jog(Direction.HAUL_IN)
        elif depth_m > line:
            self.jog(Direction.PAY_OUT, by_m=depth_m - line)
        else:
            self.jog(Direction.HAUL_IN, by_m=line - depth_m)

    def jog(self, direction: Direction, *, by_m: float | None = None) -> None:
        """Run the motor by hand (calibration): pay out or haul in until `stop`, or
        for `by_m` metres by the count.

        The end of the line, the switch and the stall rules still apply; the
        homing requirement does not (this is how an operator homes it by hand)."""
        self._halt()
        self._fault = None
        if direction is Direction.STOPPED:
            self._changed.set()
            return
        if direction is Direction.HAUL_IN and self.switch_closed and self._encoder_bad:
            # Neither witness could stop it: the switch is already closed and the
            # count is not trusted. Nothing would keep it off the block; and no haul
            # can verify home (one witness). Said to whoever asked (the stick's jog,
            # `cc-daemon winch home` through the daemon), not only in the log.
            self._changed.set()
            raise WinchFault(
                "hauling in refused: the limit switch is closed and the encoder is faulted, "
                "so nothing could stop the haul and nothing can verify home; if the probe "
                "is on board, release the station (cc-daemon release)"
            )
        if direction is Direction.HAUL_IN and by_m is None and self._at_the_block():
            return
        with self._lock:
            self._goal = Goal.TARGET
            if by_m is not None:
                target = self._edge() + int(direction) * max(1, self.drum.count_at(by_m))
            else:
                target = self._max_count if direction is Direction.PAY_OUT else -(1 << 30)
            self._target_count = min(target, self._max_count)
        self._start_motor(direction, None, homing=False)

    # ------------------------------------------------------------ starting a motion

    def _begin(self, target_m: float, *, homing: bool = False, pace: float = 1.0) -> None:
        self._halt()
        self._fault = None
        self._changed.set()
        target = self.drum.count_at(target_m)
        with self._lock:
            count = self._edge()
        if target_m == 0.0:
            if self.switch_closed and self._count_known:
                # Nothing to run: home if the count agrees (once settled), else a fault.
                reason = self._witnesses.disagreement(self.line_m, True, 0)
                if reason is not None:
                    self._distrusted(reason)
                elif not self._verified and self._settle is None:
                    self._schedule_settle(self._closed_since or self._clock.monotonic())
                return
            with self._lock:
                self._goal = Goal.HOME
            self._start_motor(Direction.HAUL_IN, None, homing=homing)
            return
        if target == count:
            return
        with self._lock:
            self._goal = Goal.TARGET
            self._target_count = min(target, self._max_count)
        direction = Direction.PAY_OUT if target > count else Direction.HAUL_IN
        self._start_motor(direction, None, homing=False, pace=pace)

    def _start_motor(
        self, direction: Direction, duty: float | None, *, homing: bool, pace: float = 1.0
    ) -> None:
        cfg = self._cfg
        self._pending = None
        off_for = time.monotonic() - self._bridge.stopped_at
        if off_for < ZERO_SETTLE_S:
            # A move replacing a running one (a cast's abort, a new target): the winding
            # may still carry current. The start waits out the rest of ZERO_SETTLE_S so
            # that the zero check below can judge the sensor (one stuck at its top would
            # otherwise pass unseen and stop every move as an overcurrent).
            start = functools.partial(
                self._start_pending, direction, duty, homing, pace, self.switch_closed
            )
            self._pending = self._loop.call_later(ZERO_SETTLE_S - off_for, start)
            self._changed.set()
            return
        # The motor is off: a sensor far from 0 A is faulty.
        self._sensing.zero_check(off_for)
        now = self._clock.monotonic()
        nominal = cfg.payout_duty if direction is Direction.PAY_OUT else cfg.haulin_duty
        self._approach_duty = nominal * APPROACH_FRACTION  # a slow motion's whole duty
        self._duty = duty or nominal * pace
        deadline = None
        if self._goal is Goal.HOME:
            # Line out / haul speed + margin; from an unknown position (start-up
            # homing) the whole line.
            line = self.max_line_m if homing or not self._homed else max(self.line_m, 0.0)
            deadline = now + line / cfg.line_speed_m_s + cfg.home_margin_s
        self._guard = MotionGuard(
            self._limits,
            started_at=now,
            home_deadline=deadline,
            direction=int(direction),
            full_speed_m_s=cfg.line_speed_m_s / nominal,  # line_speed_m_s is at the duty
            prior=self._estimate,
        )
        self._started_at = now
        self._arrived_count = None
        self._told_open_at_zero = False
        with self._lock:
            self._last_direction = direction
            self._encoder.motor_started()
        first = self._duty if cfg.ramp_s == 0 else self._duty * RAMP_FLOOR
        self._watchdog.arm()
        self._bridge.start(direction, first)
        _log.debug(
            "winch motor on",
            direction=direction.name,
            duty=self._duty,
            line_m=round(self.line_m, 3),
            goal=self._goal.value if self._goal else None,
            target_m=round(self.drum.line_m(self._target_count), 3)
            if abs(self._target_count) <= self._max_count
            else None,
        )
        self._schedule_tick()

    def _start_pending(
        self, direction: Direction, duty: float | None, homing: bool, pace: float, closed: bool
    ) -> None:
        """A start that waited for the zero. A haul in does not start if the switch
        closed meanwhile (`closed`: as it was when the start was asked for): its edge
        would have stopped the haul, had it been running. A start that fails is a
        fault, as when the start is not delayed."""
        self._pending = None
        if direction is Direction.HAUL_IN and (self.switch_closed and not closed):
            with self._lock:
                self._goal = None
            self._changed.set()
            return
        if direction is Direction.HAUL_IN and self._at_the_block():
            with self._lock:
                self._goal = None
            return
        try:
            self._start_motor(direction, duty, homing=homing, pace=pace)
        except Exception as exc:  # the caller that asked has returned: no one else hears
            self._fail(f"the motor could not be started: {type(exc).__name__}: {exc}")

    def _at_the_block(self) -> bool:
        """Both witnesses say the probe is at the block (the switch closed, the count at
        zero): a haul would only pull the motor against it until the stall rule. Home,
        once the switch has settled."""
        if not (
            self.switch_closed
            and self._count_known
            and self._distrust is None
            and self.line_m <= 0.0
        ):
            return False
        if not self._verified and self._settle is None:
            self._schedule_settle(self._closed_since or self._clock.monotonic())
        self._changed.set()
        return True

    # ------------------------------------------------------------ stopping

    def _halt(self) -> None:
        """Motor off now, and the motion over (loop side)."""
        if self._pending is not None:  # a start waiting for the zero: never comes now
            self._pending.cancel()
            self._pending = None
        try:
            self._bridge.stop()
        finally:
            self._watchdog.disarm()
            if self._tick is not None:
                self._tick.cancel()
                self._tick = None
            with self._lock:
                self._goal = None
                self._motion += 1
            guard, self._guard = self._guard, None
            if guard is not None:
                # With the count in doubt, a motion that ran without a counted pulse
                # (stopped by the switch, a verdict, an operator) moved the estimate.
                moved = guard.stopped(self._clock.monotonic())
                if moved is not None:
                    self._estimate = moved

    def _fail(self, fault: str, **detail: Any) -> None:
        self._halt()
        self._fault = fault
        self._changed.set()
        where = self._where()
        _log.error("winch fault: motor stopped", fault=fault, **where)
        self._record("winch_fault", fault=fault, **{**where, **detail})

    def _emergency_stop(self) -> None:
        """atexit: whatever state the loop was in, the motor goes off."""
        with contextlib.suppress(Exception):
            self._bridge.stop()

    def _watchdog_trip(self, silent_s: float) -> None:
        # On the watchdog thread: stop first, then tell the loop (when it runs again).
        was = self._bridge.stop()
        if was is not Direction.STOPPED:
            self._tell_loop(self._watchdog_tripped, silent_s, stopped=True)

    def _watchdog_tripped(self, silent_s: float) -> None:
        self._fail(
            f"loop watchdog: the event loop was silent for {silent_s:.2f} s "
            f"(loop_watchdog_s {self._cfg.loop_watchdog_s:g}); the motor was stopped",
            silent_s=round(silent_s, 3),
        )

    # ------------------------------------------------------------ the tick (loop side)

    def _schedule_tick(self) -> None:
        self._tick = self._loop.call_later(TICK_S, self._on_tick)

    def _on_tick(self) -> None:
        self._tick = None
        try:
            self._check()
        except Exception as exc:
            self._fail(f"winch check failed: {type(exc).__name__}: {exc}")
            _log.critical("winch check failed: motor stopped", exc_info=True)

    def _check(self) -> None:
        guard = self._guard
        if guard is None or self._bridge.direction is Direction.STOPPED:
            return
        self._watchdog.feed()
        now = self._clock.monotonic()
        current = self._sensing.current_a(motor_on=True)
        fault = guard.check(now, current, self.line_m, duty=self._bridge.duty)
        if fault is not None:
            peak = round(guard.peak_current_a, 3)
            if guard.silence is not None:
                self._silent_drum(guard.silence, peak_current_a=peak)
            else:
                self._fail(fault, peak_current_a=peak)
            return
        self._set_power(now)
        self._schedule_tick()

    def _set_power(self, now: float) -> None:
        duty = self._duty
        ramp = self._cfg.ramp_s
        if ramp > 0:
            duty *= min(1.0, RAMP_FLOOR + (1 - RAMP_FLOOR) * (now - self._started_at) / ramp)
        with self._lock:
            to_target = self._goal is Goal.TARGET
            remaining = abs(self._target_count - self._edge())
        # The last approach_m, and at least the last pulse: a count cannot see closer.
        approach = max(1, math.ceil(self._cfg.approach_m / self.drum.metres_per_pulse))
        if to_target and remaining <= approach:
            duty = min(duty, self._approach_duty)
        self._bridge.set_duty(duty)

    # ------------------------------------------------------------ handed to the loop

    def _pulse_seen(self, count: int, stop: str | None, motion: int) -> None:
        self._estimate = None  # a counted pulse: the count says where the probe is again
        if self._guard is not None:
            self._guard.pulse(self._clock.monotonic())
        if stop == "arrived" and motion != self._motion:
            # The loop ended that motion itself (a stop, a cast's abort commanding the
            # haul home) before it heard of the arrival: halting now would stop the
            # motion that replaced it, short of home with no fault (a stranded cast).
            self._changed.set()
            return
        if stop == "end of line":
            self._fail(
                f"end of line: {self.drum.line_m(count):.2f} m out reaches winch.max_line_m "
                f"{self.max_line_m:g}; the motor was stopped"
            )
        elif stop == "arrived":
            self._arrived(count)
        elif stop == "home":
            self._halt()
            _log.info("winch home by the count, the limit switch already closed")
            self._schedule_settle(self._closed_since or self._clock.monotonic())
        elif stop is not None:
            self._distrusted(stop)
        elif self._arrived_count is not None and self._bridge.direction is Direction.STOPPED:
            # A pulse after an arrival stop: the drum coasted on.
            extra = abs(count - self._arrived_count)
            self.overshoots[-1] = extra
            _log.warning(
                "winch overshoot: the drum turned on after the stop",
                pulses=extra,
                overshoot_m=round(extra * self.drum.metres_per_pulse, 3),
                line_m=round(self.drum.line_m(count), 3),
            )
        elif (
            self._goal is Goal.HOME
            and count <= 0
            and self._count_known
            and not self.at_home
            and not self._told_open_at_zero
        ):
            self._told_open_at_zero = True
            _log.warning(
                "winch count and limit switch disagree: the count says home, the switch is "
                "open; hauling on until it closes",
                counted_line_m=round(self.drum.line_m(count), 3),
                switch="open",
            )
        self._changed.set()

    def _arrived(self, count: int) -> None:
        self._halt()
        self._arrived_count = count
        self.overshoots.append(0)
        _log.debug("winch arrived", line_m=round(self.drum.line_m(count), 3))

    def _record(self, kind: str, **detail: Any) -> None:
        if self._record_sink is None:
            return
        try:
            self._record_sink(kind, **detail)
        except Exception:
            _log.error("could not journal a winch event", kind=kind, exc_info=True)
