"""Test kit for the GPIO winch: real gpiozero devices on a mock factory, a simulated drum.

`gpio_rig` opens the winch exactly as the daemon does (`open_devices` on the
factory, the drum driving the mock pins from its own thread) with settings
sized for quick tests: a 0.09 m drum at 2 pulses a turn (0.141 m a pulse),
1 m/s of line.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cc_daemon.config import WinchGpioSettings
from cc_daemon.core.winch.status import WinchStatus
from cc_daemon.drivers.winch.devices import open_devices
from cc_daemon.drivers.winch.gpio import GpioWinch
from cc_daemon.ground.clock import SystemClock
from cc_daemon.sim.drum import DrumFaults, SimulatedDrum

REPO = Path(__file__).resolve().parent.parent

FAST: dict[str, Any] = {
    "pin_factory": "mock",
    "line_speed_m_s": 1.0,
    "stall_timeout_s": 0.6,
    "home_margin_s": 1.0,
    "ramp_s": 0.1,
    # Long enough that a loaded machine pausing the loop never trips it by chance;
    # the watchdog's own tests set 0.5 s (and benchmarks/winch.py times it).
    "loop_watchdog_s": 2.0,
}


@dataclass
class GpioRig:
    winch: GpioWinch
    drum: SimulatedDrum
    events: list[tuple[str, dict[str, Any]]] = field(default_factory=list)

    @property
    def enable_pin(self) -> Any:
        return self.drum.factory.pin(self.winch._cfg.enable_pin)

    def kinds(self) -> list[str]:
        return [kind for kind, _ in self.events]

    async def settle(self, timeout: float = 30.0) -> None:
        """Wait until the motor is stopped (arrival, fault, home)."""
        async with asyncio.timeout(timeout):
            while self.winch.status().moving:
                await self.winch.wait_change(0.2)

    async def until(self, condition: Callable[[], object], timeout: float = 30.0) -> None:
        """Wait until `condition()` holds: the drum's thread or the loop makes it so.
        Each look re-arms `wait_change` (status()), so a change wakes it at once."""
        async with asyncio.timeout(timeout):
            while not condition():
                self.winch.status()
                await self.winch.wait_change(0.02)

    async def quiet(self, at_least_s: float, timeout: float = 30.0) -> list[WinchStatus]:
        """Every status seen until `at_least_s` has passed *and* no timer of the winch's
        (a switch settling, a start waiting for the zero) is still due: what a rule
        that fires after a while would have done by now, it has done, however late
        a loaded machine ran it."""
        seen: list[WinchStatus] = []
        began = time.monotonic()
        async with asyncio.timeout(timeout):
            while True:
                seen.append(self.winch.status())
                pending = self.winch._settle is not None or self.winch._pending is not None
                if not pending and time.monotonic() - began >= at_least_s:
                    await asyncio.sleep(0)  # what was due with it has run too
                    seen.append(self.winch.status())
                    return seen
                await self.winch.wait_change(0.02)


def enable_history(rig: GpioRig) -> list[tuple[float, float]]:
    """(absolute monotonic time, duty) of every change of the PWM enable pin."""
    pin = rig.enable_pin
    t = pin._last_change - sum(state.timestamp for state in pin.states[1:])
    out = []
    for state in pin.states:
        t += state.timestamp
        out.append((t, float(state.state)))
    return out


def settings(**extra: Any) -> WinchGpioSettings:
    return WinchGpioSettings.model_validate({**FAST, **extra})


@contextlib.asynccontextmanager
async def gpio_rig(
    *,
    line_m: float = 0.0,
    faults: DrumFaults | None = None,
    drum_speed_m_s: float | None = None,
    max_line_m: float = 20.0,
    start_up: bool = True,
    **cfg: Any,
) -> AsyncIterator[GpioRig]:
    gpio = settings(**cfg)
    factory = SimulatedDrum.factory_for(gpio)
    speed = drum_speed_m_s if drum_speed_m_s is not None else gpio.line_speed_m_s / gpio.payout_duty
    drum = SimulatedDrum(factory, gpio, full_speed_m_s=speed, line_m=line_m, faults=faults)
    events: list[tuple[str, dict[str, Any]]] = []
    winch = GpioWinch(
        gpio,
        open_devices(gpio, factory),
        max_line_m=max_line_m,
        clock=SystemClock(),
        record=lambda kind, **detail: events.append((kind, detail)),
        on_close=drum.close,
    )
    drum.start()
    rig = GpioRig(winch, drum, events)
    try:
        if start_up:
            await winch.start_up()
        yield rig
    finally:
        await winch.close()
        factory.reset()
