"""Motor-current and supply-voltage readings that cannot be true: a sensor fault,
judged from the readings alone (pure).

A Hall sensor (ACS712) on an ADC can fail shorted, open or noisy: a reading at
either rail of the ADC, far from zero amperes with the motor off (the zero
check), or a step between two readings of the running motor larger than a motor
on a drum can make, is the sensor, not the motor. A supply voltage outside its
configured range is the supply or the ADC it shares with the current sensor.
Either way the current cannot be trusted to see an overcurrent: the caller stops
using it and keeps the stall-by-pulses rule.
"""

from __future__ import annotations

RAIL_MARGIN = 0.002  # an ADC fraction this close to 0 or 1 is at a rail (2 LSB of 10 bits)
ZERO_TOLERANCE_A = 0.5  # with the motor off the current is 0 A, give or take this
# A motor drawing at least this under power is turning something: half as much
# again as the zero check's tolerance, so sensor offset alone never reads as turning.
TURNING_MIN_A = 1.5 * ZERO_TOLERANCE_A
# The largest step between two readings of a running motor, in units of
# max_current_a. A hard snag can take the current from running to stall within one
# 50 ms reading (a winding's L/R is about a millisecond, a drum stopped by a snag
# stops in milliseconds), so no rate tighter than "running to stall in one reading"
# is physics: the rule bounds the step, whatever the time between the readings.
# max_current_a sits above the running current (or every cast would trip it); a jam
# that quadruples a running current of up to 2/3 of it, or a start from rest into a
# stall at twice it, steps by at most 2 x max_current_a. docs/gpio-winch.md has more.
JUMP_FACTOR = 2.0


def current_fault(fraction: float, amps: float, *, motor_on: bool) -> str | None:
    """Why a current reading (ADC fraction 0..1 and its amperes) cannot be true, or None.

    At the top rail with the motor running the reading may be true: a jam drawing
    more than the sensor can read (a 5 A ACS712 on a 3.3 V ADC reads at most about
    4.3 A). It is left to the overcurrent rule (max_current_a is below the top, the
    configuration says so), which stops the motor; a sensor stuck there is found at
    the zero check before the next move."""
    top = fraction >= 1 - RAIL_MARGIN
    if fraction <= RAIL_MARGIN or (top and not motor_on):
        return f"motor current sensor at a rail (ADC {fraction:.3f} of full scale, {amps:.2f} A)"
    if not motor_on and abs(amps) > ZERO_TOLERANCE_A:
        return (
            f"motor current sensor reads {amps:.2f} A with the motor off "
            f"(zero check: within {ZERO_TOLERANCE_A:g} A)"
        )
    return None


def jump_limit_a(max_current_a: float) -> float:
    """The largest step between two consecutive readings of a running motor."""
    return JUMP_FACTOR * max_current_a


def current_jump_fault(previous_a: float, amps: float, *, max_current_a: float) -> str | None:
    """Why a reading cannot follow the previous one, both taken with the motor running
    (one motion, consecutive), or None."""
    limit = jump_limit_a(max_current_a)
    step = abs(amps - previous_a)
    if step <= limit:
        return None
    return (
        f"motor current sensor jumped from {previous_a:.2f} A to {amps:.2f} A between two "
        f"readings with the motor running: a step of {step:.2f} A, more than a motor on a "
        f"drum can make ({limit:g} A, {JUMP_FACTOR:g} x max_current_a)"
    )


def supply_fault(volts: float, *, min_v: float, max_v: float) -> str | None:
    """Why a supply voltage reading cannot be true (outside min_v..max_v), or None."""
    if min_v <= volts <= max_v:
        return None
    side = f"below supply_min_v {min_v:g} V" if volts < min_v else f"above supply_max_v {max_v:g} V"
    return f"supply voltage reads {volts:.2f} V, {side}: the supply or the ADC is faulty"
