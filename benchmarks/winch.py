"""GPIO winch benchmark: how fast the motor goes off, on gpiozero's mock pins.

Three figures (not tests):
- limit switch edge -> motor enable pin low: the switch pin is driven high on a
  thread (as gpiozero's callback thread would see it) while the motor hauls in;
  timed from just before the edge to the PWM pin's recorded change to 0;
- blocked event loop -> the watchdog thread stopping the motor: the loop is
  blocked with the motor running; timed from the block to the pin going low,
  against the configured `loop_watchdog_s`;
- one MCP3008 reading (the supply channel) through gpiozero's software SPI on
  mock pins, answered by the simulated drum: what the winch's sensor checks cost
  the event loop on each reading (the current each 50 ms tick, the supply once a
  second while running and at each zero check).

On a Pi, lgpio's edge detection adds its own delay before gpiozero's callback;
this measures what the daemon adds on top.

    python -m benchmarks          (or: make bench)
"""

from __future__ import annotations

import asyncio
import statistics
import sys
import threading
import time
from typing import Any

from cc_daemon.config import WinchGpioSettings
from cc_daemon.drivers.winch.devices import open_devices
from cc_daemon.drivers.winch.gpio import GpioWinch
from cc_daemon.drivers.winch.motor import Direction
from cc_daemon.ground.clock import SystemClock
from cc_daemon.sim.drum import MockWinchFactory, SimulatedDrum

SWITCH_TRIALS = 300
WATCHDOG_TRIALS = 8
ADC_READS = 500


def _pin_went_low_at(pin: Any, after: float) -> float | None:
    """The monotonic time the mock pin changed to 0 after `after`, from its history."""
    t = pin._last_change - sum(state.timestamp for state in pin.states[1:])
    for state in pin.states:
        t += state.timestamp
        if t >= after and float(state.state) == 0.0:
            return t
    return None


async def _open(**cfg: Any) -> tuple[GpioWinch, MockWinchFactory, WinchGpioSettings]:
    settings = WinchGpioSettings.model_validate(
        {"pin_factory": "mock", "stall_timeout_s": 10, "ramp_s": 0, **cfg}
    )
    factory = MockWinchFactory({settings.enable_pin})
    winch = GpioWinch(settings, open_devices(settings, factory), max_line_m=20, clock=SystemClock())
    return winch, factory, settings


def _edge(switch: Any, stamp: list[float]) -> None:
    stamp.append(time.monotonic())
    switch.drive_high()  # gpiozero calls the winch on this thread


async def _switch_latency() -> list[float]:
    winch, factory, cfg = await _open()
    enable, switch = factory.pin(cfg.enable_pin), factory.pin(cfg.switch_pin)
    out: list[float] = []
    try:
        for _ in range(SWITCH_TRIALS):
            switch.drive_low()
            await asyncio.sleep(0)
            winch.jog(Direction.HAUL_IN)
            enable.clear_states()
            stamp: list[float] = []
            thread = threading.Thread(target=_edge, args=(switch, stamp))
            thread.start()
            thread.join()
            low = _pin_went_low_at(enable, stamp[0])
            assert low is not None, "the motor did not stop at the switch"
            out.append(low - stamp[0])
            await asyncio.sleep(0)  # the loop hears of it, as in the daemon
    finally:
        await winch.close()
    return out


async def _watchdog_latency(timeout_s: float, trials: int) -> list[float]:
    winch, factory, cfg = await _open(loop_watchdog_s=timeout_s)
    enable = factory.pin(cfg.enable_pin)
    out: list[float] = []
    try:
        for _ in range(trials):
            winch.jog(Direction.PAY_OUT)
            await asyncio.sleep(0.1)  # running, fed by its tick
            blocked = time.monotonic()
            time.sleep(timeout_s * 1.5)  # noqa: ASYNC251 - the point: the event loop is stuck
            low = _pin_went_low_at(enable, blocked)
            assert low is not None, "the watchdog did not stop the motor"
            out.append(low - blocked)
            await asyncio.sleep(0.05)  # the loop runs again: the fault is noted
    finally:
        await winch.close()
    return out


def _adc_reads() -> tuple[list[float], float]:
    """Wall time of each supply reading, and the CPU time of all of them."""
    cfg = WinchGpioSettings.model_validate({"pin_factory": "mock", "adc": True})
    factory = SimulatedDrum.factory_for(cfg)
    drum = SimulatedDrum(factory, cfg)
    devices = open_devices(cfg, factory)
    assert devices.voltage is not None
    out: list[float] = []
    try:
        devices.voltage.value  # noqa: B018 - the first read sets the bus up
        cpu = time.process_time()
        for _ in range(ADC_READS):
            start = time.perf_counter()
            devices.voltage.value  # noqa: B018 - the read is the point
            out.append(time.perf_counter() - start)
        cpu = time.process_time() - cpu
    finally:
        devices.close()
        drum.close()
        factory.reset()
    return out, cpu


def _ms(values: list[float]) -> str:
    ordered = sorted(values)
    p99 = ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))]
    return (
        f"median {statistics.median(values) * 1e3:8.3f} ms   p99 {p99 * 1e3:8.3f} ms   "
        f"max {max(values) * 1e3:8.3f} ms   (n={len(values)})"
    )


def main() -> int:
    from cc_daemon.ground.logsetup import configure_logging

    configure_logging("console", "critical", sys.stderr)  # the figures, not the winch's log
    switch = asyncio.run(_switch_latency())
    print(f"limit switch edge -> motor pin low:           {_ms(switch)}")
    for timeout_s, trials in ((0.2, WATCHDOG_TRIALS), (1.0, 3)):
        watchdog = asyncio.run(_watchdog_latency(timeout_s, trials))
        print(f"blocked loop -> watchdog stop (limit {timeout_s:g} s): {_ms(watchdog)}")
        late = max(watchdog) - timeout_s
        print(f"   at most {late * 1e3:.1f} ms after loop_watchdog_s")
    reads, cpu = _adc_reads()
    print(f"one MCP3008 reading on mock pins:             {_ms(reads)}")
    print(f"   {cpu / len(reads) * 1e3:.3f} ms of CPU a reading")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
