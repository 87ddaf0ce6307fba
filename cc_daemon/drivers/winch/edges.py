"""The GPIO winch's edges, on gpiozero's thread: each drum pulse and switch edge.

`EdgeCounting` is a base of `gpio.GpioWinch`: gpiozero calls these callbacks on
its own thread (the simulated drum's, on mock pins). It owns the count (the
drum's position as the index of the mark last passed going out), the encoder's
judgement of each pulse (`core.winch.encoder`), and the stops that cannot wait
for the loop: the target count, the end of the line, the limit switch, the
witnesses disagreeing at an edge. Under the winch's lock the motor is only ever
*stopped* here; everything else is handed to the event loop with
`call_soon_threadsafe` (`_tell_loop`). A stop made here is counted in flight
until the loop has heard why: until then the winch's status says it is still
moving, never "stopped, no fault" short of its target (seen under load: a pulse
storm's stop read as a motion that had simply ended at 1.27 m); an arrival heard
after the loop has itself ended that motion (a cast's abort commanding the haul
home) stops nothing more. Once the winch is closed, what was still on its way to
the loop is dropped: the pins it would touch are closed. Its state is set up by
`GpioWinch.__init__`.
"""

from __future__ import annotations

import asyncio
import enum
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cc_daemon.core.winch.drum import Drum
from cc_daemon.core.winch.encoder import EncoderJudge
from cc_daemon.core.winch.witness import Witnesses
from cc_daemon.drivers.winch.motor import Direction, HBridge
from cc_daemon.ground.clock import Clock


class Goal(enum.Enum):
    TARGET = "target"  # stop at a pulse count
    HOME = "home"  # haul in until the limit switch closes


class EdgeCounting:
    """Pulses and switch edges on gpiozero's thread (see the module docstring)."""

    _bridge: HBridge
    _clock: Clock
    _loop: asyncio.AbstractEventLoop
    _lock: threading.Lock
    _count: int
    _last_step: int
    _count_known: bool
    _switch_now: bool
    _last_direction: Direction
    _max_count: int
    _goal: Goal | None
    _target_count: int
    _encoder: EncoderJudge
    _encoder_bad: str | None
    _ignored: int
    _witnesses: Witnesses
    _stops_in_flight: int
    _motion: int  # bumped by the loop each time it ends a motion (`GpioWinch._halt`)
    _closed: bool
    drum: Drum

    if TYPE_CHECKING:  # the loop side's, in GpioWinch and its other bases

        def _encoder_faulted(self, reason: str) -> None: ...

        def _pulse_seen(self, count: int, stop: str | None, motion: int) -> None: ...

        def _switch_seen(self, closed: bool, running: Direction) -> None: ...

    def _edge(self) -> int:
        """The count at the last edge (under _lock): where the line was when it was seen."""
        return self._count + (1 if self._last_step < 0 else 0)

    def _pulse_thread(self) -> None:
        with self._lock:
            # Single channel: the direction is the motor's, or the last one it had
            # (a drum still turning after a stop).
            running = self._bridge.direction
            step = int(running) if running is not Direction.STOPPED else int(self._last_direction)
        self._count_thread(step)

    def _step_out_thread(self) -> None:
        self._count_thread(1)

    def _step_in_thread(self) -> None:
        self._count_thread(-1)

    def _count_thread(self, step: int) -> None:
        stop = None
        now = self._clock.monotonic()
        with self._lock:
            if self._encoder_bad is not None:
                self._ignored += 1  # a storm: the least possible, and nothing to the loop
                return
            bad = self._encoder.pulse(now, self._bridge.direction is not Direction.STOPPED)
            if bad is not None:
                self._encoder_bad = bad
                self._bridge.stop()
        if bad is not None:
            self._tell_loop(self._encoder_faulted, bad, stopped=True)
            return
        with self._lock:
            self._count += step
            self._last_step = step
            count = self._edge()
            running = self._bridge.direction
            closed = self._switch_now
            if running is Direction.PAY_OUT and count >= self._max_count:
                stop = "end of line"
            elif running is not Direction.STOPPED and self._count_known:
                # The witnesses, at every edge of a motion: a switch still closed
                # well into a descent, or hauling on past zero with it open.
                if running is Direction.HAUL_IN and closed and self._count <= 0:
                    stop = "home"  # the switch was already closed: the count says we are in
                else:
                    stop = self._witnesses.disagreement(
                        self.drum.line_m(count), closed, int(running)
                    )
            if stop is None and (
                self._goal is Goal.TARGET
                and (
                    (running is Direction.PAY_OUT and count >= self._target_count)
                    or (running is Direction.HAUL_IN and count <= self._target_count)
                )
            ):
                stop = "arrived"
            if stop is not None:
                self._bridge.stop()
            motion = self._motion  # the motion this stop ended
        self._tell_loop(self._pulse_seen, count, stop, motion, stopped=stop is not None)

    def _switch_closed_thread(self) -> None:
        with self._lock:
            self._switch_now = True
            running = self._bridge.direction
            if running is Direction.PAY_OUT and self._edge() <= 0:
                # Still within the first pulse of leaving the block: the switch
                # bouncing open, not a snag.
                running = Direction.STOPPED
            elif running is not Direction.STOPPED:
                self._bridge.stop()
        self._tell_loop(self._switch_seen, True, running, stopped=running is not Direction.STOPPED)

    def _switch_opened_thread(self) -> None:
        with self._lock:
            self._switch_now = False
        self._tell_loop(self._switch_seen, False, self._bridge.direction)

    def _tell_loop(self, callback: Callable[..., None], *args: Any, stopped: bool = False) -> None:
        """Hand `callback(*args)` to the loop; `stopped`: this thread stopped the motor,
        and the status keeps saying "moving" until the loop has heard why."""
        if stopped:
            with self._lock:
                self._stops_in_flight += 1
        try:
            self._loop.call_soon_threadsafe(self._heard, callback, stopped, args)
        except RuntimeError:  # the loop is closed: the motor is already off
            if stopped:
                with self._lock:
                    self._stops_in_flight -= 1

    def _heard(self, callback: Callable[..., None], stopped: bool, args: tuple[Any, ...]) -> None:
        """On the loop: what a thread told it, unless the winch has closed meanwhile."""
        if stopped:
            with self._lock:
                self._stops_in_flight -= 1
        if not self._closed:
            callback(*args)
