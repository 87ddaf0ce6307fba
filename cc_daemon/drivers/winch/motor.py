"""The H-bridge: two direction pins and a PWM enable, safe to stop from any thread.

It owns the order in which the pins change (power off first, then direction,
then power) and a lock so that a stop from gpiozero's callback thread or the
loop watchdog cannot interleave with a start from the event loop. It never
decides when to move: the winch does.
"""

from __future__ import annotations

import threading
import time
from enum import IntEnum
from typing import Protocol


class Direction(IntEnum):
    HAUL_IN = -1
    STOPPED = 0
    PAY_OUT = 1


class _Switch(Protocol):
    def on(self) -> None: ...

    def off(self) -> None: ...

    def close(self) -> None: ...


class _Pwm(Protocol):
    value: float

    def close(self) -> None: ...


class HBridge:
    def __init__(self, pay_out: _Switch, haul_in: _Switch, enable: _Pwm) -> None:
        self._pay_out = pay_out
        self._haul_in = haul_in
        self._enable = enable
        self._lock = threading.Lock()
        self._direction = Direction.STOPPED
        self._duty = 0.0
        self._closed = False
        self.stopped_at = -1e9  # time.monotonic() of the last stop of a running motor
        self.stop()

    @property
    def direction(self) -> Direction:
        return self._direction

    @property
    def duty(self) -> float:
        return self._duty

    def start(self, direction: Direction, duty: float) -> None:
        if direction is Direction.STOPPED:
            raise ValueError("start needs a direction; use stop()")
        with self._lock:
            if self._closed:
                raise RuntimeError("the H-bridge is closed")
            # Never both direction pins high, never a direction change under power.
            self._enable.value = 0.0
            (self._haul_in if direction is Direction.PAY_OUT else self._pay_out).off()
            (self._pay_out if direction is Direction.PAY_OUT else self._haul_in).on()
            self._direction = direction
            self._set_duty(duty)

    def set_duty(self, duty: float) -> None:
        """Change the power of a running motor; a stopped motor stays stopped."""
        with self._lock:
            if self._direction is not Direction.STOPPED:
                self._set_duty(duty)

    def stop(self) -> Direction:
        """Power off, then both direction pins low. Returns the direction it was running in."""
        with self._lock:
            was = self._direction
            if was is not Direction.STOPPED:
                self.stopped_at = time.monotonic()
            self._direction = Direction.STOPPED
            self._duty = 0.0
            try:
                self._enable.value = 0.0
            finally:
                self._pay_out.off()
                self._haul_in.off()
            return was

    def close(self) -> None:
        try:
            self.stop()
        finally:
            with self._lock:
                self._closed = True
            for device in (self._enable, self._pay_out, self._haul_in):
                device.close()

    def _set_duty(self, duty: float) -> None:
        self._duty = min(max(duty, 0.0), 1.0)
        self._enable.value = self._duty
