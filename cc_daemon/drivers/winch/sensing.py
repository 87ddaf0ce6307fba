"""The GPIO winch's motor current and supply voltage, through the MCP3008, and the
sensors' own faults.

It owns reading the two ADC channels and deciding, with `core.winch.sensors`,
that a reading cannot be true: the current at a rail, off zero with the motor
off (the zero check before every move), or stepping between two readings of the
running motor by more than a motor on a drum can; the supply outside
`supply_min_v`..`supply_max_v` (read at the zero check and once every
`SUPPLY_EVERY` readings of the running motor). Any of them and `current_a`
answers None from then on (the winch falls back to stall-by-pulses), until the
daemon restarts: the supply and the current share the ADC and its reference, so
a supply that cannot be true leaves the current untrusted too. Each kind of
fault is said once (log and journal, with the figures) and the fallback once; a
supply still out of range afterwards is summed up in the log at most once a
second. It never touches the motor, and never raises for a sensor that cannot
be read (that is the same fault: the pulses still guard the motor).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import structlog

from cc_daemon.config import WinchGpioSettings
from cc_daemon.core.winch.drum import CurrentSensor, VoltageDivider
from cc_daemon.core.winch.sensors import current_fault, current_jump_fault, supply_fault
from cc_daemon.drivers.winch.devices import GpioDevices

_log = structlog.get_logger("cc_daemon.winch.gpio")

# Readings of the running motor (one each 50 ms tick of the winch) between two
# readings of the supply: once a second. A read of the MCP3008 on mock pins costs
# about 0.45 ms of CPU (`python -m benchmarks.winch`, docs/gpio-winch.md): the
# current's readings take about 1 % of a core while the motor runs, and the supply
# adds a twentieth of that.
SUPPLY_EVERY = 20
# A motor stopped this recently may still carry its winding's current (L/R is about a
# millisecond for a small DC motor, the flyback diodes' decay a few): not yet a zero.
ZERO_SETTLE_S = 0.02
SUMMARY_S = 1.0  # a supply still out of range is summed up in the log this often at most


class MotorSensing:
    def __init__(
        self,
        cfg: WinchGpioSettings,
        devices: GpioDevices,
        record: Callable[..., None],
        *,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self._dev = devices
        self._record = record
        self._monotonic = monotonic
        self._current = CurrentSensor(cfg.adc_vref_v, cfg.current_zero_v, cfg.current_v_per_a)
        self._divider = VoltageDivider(cfg.adc_vref_v, cfg.divider_r1_ohm, cfg.divider_r2_ohm)
        self._max_current_a = cfg.max_current_a
        self._supply_min_v = cfg.supply_min_v
        self._supply_max_v = cfg.supply_max_v
        self._faults: dict[str, str] = {}  # kind ("current", "supply") -> what was found
        self._previous_a: float | None = None  # the last reading of this motion's running motor
        self._running_reads = 0  # readings of the running motor since the zero check
        self._supply_bad = 0  # supply readings that could not be true since its fault
        self._supply_bad_told = 0
        self._supply_told_at: float | None = None

    @property
    def fault(self) -> str | None:
        """Every sensor fault found, in order; with any of them the current is not used."""
        return "; ".join(self._faults.values()) or None

    def raw_current_a(self) -> float | None:
        """The reading as it is, trusted or not (for `cc-daemon winch`)."""
        if self._dev.current is None:
            return None
        return self._current.amps(float(self._dev.current.value))

    def current_a(self, *, motor_on: bool) -> float | None:
        """The motor current, or None: no sensor, or a sensor fault found. A reading
        of the running motor is judged against the one before it in the motion, and
        every `SUPPLY_EVERY`-th also reads and judges the supply."""
        if motor_on:
            self._running_reads += 1
            if self._running_reads % SUPPLY_EVERY == 0:
                self.check_supply()
        if self._dev.current is None or self._faults:
            return None
        try:
            fraction = float(self._dev.current.value)
        except Exception as exc:
            self._found("current", f"motor current sensor could not be read: {_why(exc)}")
            return None
        amps = self._current.amps(fraction)
        fault = current_fault(fraction, amps, motor_on=motor_on)
        previous = self._previous_a
        if fault is None and motor_on and previous is not None:
            fault = current_jump_fault(previous, amps, max_current_a=self._max_current_a)
        if fault is not None:
            detail: dict[str, Any] = {"fraction": round(fraction, 4), "amps": round(amps, 3)}
            if previous is not None and motor_on:
                detail["previous_amps"] = round(previous, 3)
            self._found("current", fault, **detail)
            return None
        self._previous_a = amps if motor_on else None
        return amps

    def zero_check(self, off_for_s: float = math.inf) -> None:
        """Before a move, the motor off: the current far from 0 A, or the supply out of
        its range, is a sensor fault before the move. Never raises: a sensor that
        cannot be read is a faulty sensor, not a reason to refuse the move (the
        pulses still guard it). Starts a new motion for the jump rule. A motor off
        for less than `ZERO_SETTLE_S` (a move replacing a running one) may still
        carry its winding's current: the zero is not judged then."""
        self._previous_a = None
        self._running_reads = 0
        if off_for_s >= ZERO_SETTLE_S:
            try:
                self.current_a(motor_on=False)
            except Exception as exc:
                self._found("current", f"motor current sensor could not be read: {_why(exc)}")
        self.check_supply()

    def supply_v(self) -> float | None:
        """The supply as read, trusted or not (for `cc-daemon winch`)."""
        if self._dev.voltage is None:
            return None
        return self._divider.volts(float(self._dev.voltage.value))

    def check_supply(self) -> None:
        """Read the supply and judge it against its range. Never raises."""
        if self._dev.voltage is None:
            return
        detail: dict[str, Any] = {}
        try:
            volts = self.supply_v()
        except Exception as exc:
            fault: str | None = f"supply voltage could not be read: {_why(exc)}"
        else:
            assert volts is not None
            fault = supply_fault(volts, min_v=self._supply_min_v, max_v=self._supply_max_v)
            detail = {
                "supply_v": round(volts, 2),
                "supply_min_v": self._supply_min_v,
                "supply_max_v": self._supply_max_v,
            }
        if fault is None:
            return
        if "supply" not in self._faults:
            self._found("supply", fault, **detail)
            return
        self._supply_bad += 1
        now = self._monotonic()
        if self._supply_told_at is None or now - self._supply_told_at >= SUMMARY_S:
            _log.warning(
                "winch supply still cannot be true",
                readings=self._supply_bad - self._supply_bad_told,
                since_fault=self._supply_bad,
                latest=fault,
                **detail,
            )
            self._supply_bad_told = self._supply_bad
            self._supply_told_at = now

    def _found(self, kind: str, fault: str, **detail: Any) -> None:
        """Say a sensor fault once per kind; the fallback with the first of them."""
        if kind in self._faults:
            return
        first = not self._faults
        self._faults[kind] = fault
        if kind == "supply":
            self._supply_told_at = self._monotonic()
        if first:
            _log.error(
                "winch sensor fault: overcurrent protection falls back to stall-by-pulses",
                sensor=kind,
                fault=fault,
                **detail,
            )
            self._record(
                "winch_sensor_fault", sensor=kind, fault=fault, fallback="stall-by-pulses", **detail
            )
            return
        _log.error(
            "winch sensor fault (overcurrent protection already by pulses)",
            sensor=kind,
            fault=fault,
            **detail,
        )
        self._record("winch_sensor_fault", sensor=kind, fault=fault, **detail)


def _why(exc: Exception) -> str:
    return f"{type(exc).__name__}: {exc}"
