"""Motor-current readings that cannot be true: a sensor fault, judged from the reading
alone (pure).

A Hall sensor (ACS712) on an ADC can fail shorted, open or noisy: a reading at
either rail of the ADC, or far from zero amperes with the motor off (the zero
check), is the sensor, not the motor. Such a sensor cannot be trusted to see an
overcurrent: the caller stops using it and keeps the stall-by-pulses rule.
"""

from __future__ import annotations

RAIL_MARGIN = 0.002  # an ADC fraction this close to 0 or 1 is at a rail (2 LSB of 10 bits)
ZERO_TOLERANCE_A = 0.5  # with the motor off the current is 0 A, give or take this


def current_fault(fraction: float, amps: float, *, motor_on: bool) -> str | None:
    """Why a current reading (ADC fraction 0..1 and its amperes) cannot be true, or None."""
    if fraction <= RAIL_MARGIN or fraction >= 1 - RAIL_MARGIN:
        return f"motor current sensor at a rail (ADC {fraction:.3f} of full scale, {amps:.2f} A)"
    if not motor_on and abs(amps) > ZERO_TOLERANCE_A:
        return (
            f"motor current sensor reads {amps:.2f} A with the motor off "
            f"(zero check: within {ZERO_TOLERANCE_A:g} A)"
        )
    return None
