"""The winch interface every backend implements.

It is shaped for a motor with a direction, a home limit switch and a drum
encoder: the cast asks for a depth, the winch runs towards it and stops by
itself on arrival, on a fault (stall, jam, lost encoder) or when told to stop.
The winch, not the cast, decides when a target is reached, because only it
knows its encoder's resolution.

Contract:
- `move_to` starts a motion and returns at once; it clears a previous fault
  (it is a new attempt) or raises `WinchFault` if the backend refuses.
- `stop` stops the motor and never raises for a motor that is already stopped.
- `status` is cheap and never blocks.
- `wait_change` returns when the status may have changed (arrival, fault,
  stop) or after `timeout` seconds, whichever is first.
- `close` leaves the motor stopped, whatever state it was in.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable


class WinchStatus(NamedTuple):
    depth_m: float  # probe depth below the surface, >= 0
    moving: bool
    at_home: bool  # the home limit switch (or the model of it) is made
    fault: str | None  # why the winch last stopped short, if it did
    # A sensor found untrustworthy and no longer used (the motor current or the
    # supply: overcurrent by pulses only); the winch still moves.
    sensor_fault: str | None = None
    # While the count is in doubt (a dead or babbling encoder), `depth_m` is a best
    # estimate and the probe is somewhere in [depth_low_m, depth_high_m]; None when
    # the depth is measured.
    depth_low_m: float | None = None
    depth_high_m: float | None = None


HOMING_FAILED = "homing failed"  # how a start-up homing fault's text begins


def verified_home(status: WinchStatus) -> bool:
    """Home as R-F may rely on: the winch says home, is still, and its start-up
    homing has not failed (a winch that could not home cannot vouch for home)."""
    return (
        status.at_home
        and not status.moving
        and not (status.fault is not None and status.fault.startswith(HOMING_FAILED))
    )


def refuses_casts(status: WinchStatus) -> bool:
    """A winch no cast may start on: its homing failed, or it reports a fault with
    the probe not verified home (the probe may be down and nothing can vouch)."""
    if status.fault is None:
        return False
    return status.fault.startswith(HOMING_FAILED) or not status.at_home


class Winch(Protocol):
    def status(self) -> WinchStatus: ...

    def move_to(self, depth_m: float) -> None: ...

    def stop(self) -> None: ...

    async def wait_change(self, timeout: float) -> None: ...

    async def close(self) -> None: ...


# Near a target (within approach_m) a winch slows to this fraction of its speed,
# and a slow motion (a blind descent) runs at it the whole way: every backend alike.
APPROACH_FRACTION = 0.5


@runtime_checkable
class ApproachSpeed(Protocol):
    """A winch that can run a whole move at its approach speed (the speed it slows
    to near a target): a blind cast pays out at it, the bed being anywhere below.
    A backend without it runs a blind cast's moves at its one speed."""

    def move_slowly_to(self, depth_m: float) -> None: ...


@runtime_checkable
class LimitedSpeed(Protocol):
    """A winch that can run a move no faster than a given speed, and no slower than its
    approach speed (the slowest it runs steadily): a profile's descent asks for it.
    A backend without it runs the move at its own speed (the daemon says so)."""

    def move_at_most(self, depth_m: float, speed_m_s: float) -> None: ...
