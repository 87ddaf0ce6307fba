"""The GPIO winch's motor current and supply voltage, through the MCP3008, and the
current sensor's own faults.

It owns reading the two ADC channels and deciding, with
`core.winch.sensors.current_fault`, that the current sensor cannot be trusted:
then `current_a` answers None (the winch falls back to stall-by-pulses), the
fault is said once (log and journal) and the readings are not used again until
the daemon restarts. It never touches the motor.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import structlog

from cc_daemon.config import WinchGpioSettings
from cc_daemon.core.winch.drum import CurrentSensor, VoltageDivider
from cc_daemon.core.winch.sensors import current_fault
from cc_daemon.drivers.winch.devices import GpioDevices

_log = structlog.get_logger("cc_daemon.winch.gpio")


class MotorSensing:
    def __init__(
        self, cfg: WinchGpioSettings, devices: GpioDevices, record: Callable[..., None]
    ) -> None:
        self._dev = devices
        self._record = record
        self._current = CurrentSensor(cfg.adc_vref_v, cfg.current_zero_v, cfg.current_v_per_a)
        self._divider = VoltageDivider(cfg.adc_vref_v, cfg.divider_r1_ohm, cfg.divider_r2_ohm)
        self.fault: str | None = None  # the current sensor's, once found

    def raw_current_a(self) -> float | None:
        """The reading as it is, trusted or not (for `cc-daemon winch`)."""
        if self._dev.current is None:
            return None
        return self._current.amps(float(self._dev.current.value))

    def current_a(self, *, motor_on: bool) -> float | None:
        """The motor current, or None: no sensor, or one found faulty."""
        if self._dev.current is None or self.fault is not None:
            return None
        fraction = float(self._dev.current.value)
        amps = self._current.amps(fraction)
        fault = current_fault(fraction, amps, motor_on=motor_on)
        if fault is not None:
            self._found(fault, fraction=round(fraction, 4), amps=round(amps, 3))
            return None
        return amps

    def zero_check(self) -> None:
        """Read the sensor with the motor off: far from 0 A, it is faulty before the move.
        Never raises: a sensor that cannot be read is a faulty sensor, not a reason to
        refuse the move (the pulses still guard it)."""
        try:
            self.current_a(motor_on=False)
        except Exception as exc:
            self._found(f"motor current sensor could not be read: {type(exc).__name__}: {exc}")

    def supply_v(self) -> float | None:
        if self._dev.voltage is None:
            return None
        return self._divider.volts(float(self._dev.voltage.value))

    def _found(self, fault: str, **detail: Any) -> None:
        self.fault = fault
        _log.error(
            "winch current sensor fault: overcurrent protection falls back to stall-by-pulses",
            fault=fault,
            **detail,
        )
        self._record("winch_sensor_fault", fault=fault, fallback="stall-by-pulses", **detail)
