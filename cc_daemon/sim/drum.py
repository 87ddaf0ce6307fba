"""A simulated drum on gpiozero's MockFactory: the GPIO winch without a winch.

It owns a small physical model on its own thread: it reads the mock H-bridge
pins (direction and PWM duty), turns a drum at `full_speed_m_s x duty`, drives
the mock pulse pin (or the two quadrature pins) as the drum turns, closes the
mock limit switch when the line is in, and answers the MCP3008's SPI
transactions with a motor current and a supply voltage. Faults can be
injected: a jammed drum, a snag that closes the switch on the way down, a
switch that never closes, a slow haul, lost pulses, a pulse pin that babbles
or goes silent for ever, a current sensor stuck or noisy, a supply voltage out
of its range.

It is for tests, benchmarks, `--simulate --winch gpio-mock` and demos; it
never runs on a native pin factory. Because mock pins call their callbacks in
the thread that changes them, gpiozero's callbacks arrive on this drum's thread
as they would on gpiozero's own thread on a Pi.
"""

from __future__ import annotations

import math
import random
import threading
import time
from dataclasses import dataclass
from typing import Any

from gpiozero import Device, OutputDevice
from gpiozero.devices import SharedMixin
from gpiozero.pins.mock import MockFactory, MockPWMPin, MockSPIDevice, MockSPIInterface
from gpiozero.pins.spi import SPISoftwareBus

from cc_daemon.config import Settings, WinchGpioSettings
from cc_daemon.core.winch.drum import CurrentSensor, Drum, VoltageDivider, current_fraction

# The MCP3008 on SPI0 as gpiozero's software SPI sees it on a mock factory.
_SPI0 = {"clock_pin": 11, "mosi_pin": 10, "miso_pin": 9}
_QUADRATURE = ((False, False), (True, False), (True, True), (False, True))


class _FactoryDevice(Device):  # type: ignore[misc]
    """Placed after SPISoftwareBus in the MRO: gpiozero 2.0.1's software SPI bus calls
    Device.__init__ without its pin factory, which would look up (and set) the
    global default factory; this hands it the bus's own factory instead."""

    bus_factory: Any = None

    def __init__(self, *, pin_factory: Any = None) -> None:
        super().__init__(pin_factory=pin_factory or self.bus_factory)


class _Bus(SPISoftwareBus, _FactoryDevice):  # type: ignore[misc]
    @classmethod
    def _shared_key(cls, clock_pin: Any, mosi_pin: Any, miso_pin: Any, *, pin_factory: Any) -> Any:
        # Shared per factory, not per process: each test has its own mock pins.
        return (id(pin_factory), clock_pin, mosi_pin, miso_pin)


class _MockSPI(MockSPIInterface):  # type: ignore[misc]
    """gpiozero's mock software SPI, on a bus that keeps to its own factory."""

    def __init__(
        self, clock_pin: Any, mosi_pin: Any, miso_pin: Any, select_pin: Any, *, pin_factory: Any
    ) -> None:
        self._bus = None
        self._select = None
        Device.__init__(self, pin_factory=pin_factory)
        try:
            self._clock_phase = False
            self._lsb_first = False
            self._bits_per_word = 8
            bus = type("_FactoryBus", (_Bus,), {"bus_factory": pin_factory})
            self._bus = bus(clock_pin, mosi_pin, miso_pin, pin_factory=pin_factory)
            self._select = OutputDevice(select_pin, active_high=False, pin_factory=pin_factory)
        except BaseException:
            self.close()
            raise


class _MockSPIShared(SharedMixin, _MockSPI):  # type: ignore[misc]
    """Both MCP3008 channels share one chip select, as on the board."""

    @classmethod
    def _shared_key(
        cls, clock_pin: Any, mosi_pin: Any, miso_pin: Any, select_pin: Any, *, pin_factory: Any
    ) -> Any:
        return (id(pin_factory), clock_pin, select_pin)


class MockWinchFactory(MockFactory):  # type: ignore[misc]
    """A MockFactory whose `pwm_pins` are PWM-capable (the rest plain mock pins)."""

    def __init__(self, pwm_pins: set[int]) -> None:
        super().__init__()
        self._pwm_names = {f"GPIO{pin}" for pin in pwm_pins}

    def _get_spi_class(self, shared: bool, hardware: bool) -> Any:
        return _MockSPIShared if shared else _MockSPI

    def pin(self, name: Any, pin_class: Any = None, **kwargs: Any) -> Any:
        if pin_class is None:
            for _header, info in self.board_info.find_pin(name):
                if info.name in self._pwm_names:
                    pin_class = MockPWMPin
                break
        return super().pin(name, pin_class=pin_class, **kwargs)


class _MockMCP3008(MockSPIDevice):  # type: ignore[misc]
    """The slave side of an MCP3008: answers a single-ended read of a channel."""

    def __init__(self, factory: MockFactory, select_pin: int, read: Any) -> None:
        super().__init__(select_pin=select_pin, pin_factory=factory, **_SPI0)
        self._read_channel = read

    def on_bit(self) -> None:
        # Tx 0000000 1 M CCC ..., Rx ... x 0 R9..R0: answer once the channel is in.
        if self.rx_bit == 12:
            bits = self.rx_buf[9:12]
            channel = bits[0] << 2 | bits[1] << 1 | bits[2]
            fraction = min(max(float(self._read_channel(channel)), 0.0), 1.0)
            self.tx_word(round(fraction * 1023), 12)


SNAG_AT_M = 1.0  # --winch-fault snag: the switch closes here on the way down
STORM_AT_M = 1.0  # --winch-fault pulse-storm: the pulse pin babbles from here on
STORM_PULSES_PER_STEP = 10  # a babbling pin: 10 pulses a 1 ms step, 10,000 a second
ENCODER_DEAD_FROM_M = 1.0  # --winch-fault encoder-dead: the first haul in from deeper kills it


@dataclass
class DrumFaults:
    jam_at_m: float | None = None  # the drum stops turning here on the way out
    jam_in_at_m: float | None = None  # ... or here on the way in (a line caught on the way up)
    snag_at_m: float | None = None  # the switch closes here on the way out
    switch_stuck_open: bool = False  # the switch never closes
    switch_stuck_closed: bool = False  # the switch never opens (a shorted wire)
    lose_every: int = 0  # every n-th pulse paying out is lost (a slipping line), 0 = none
    # The first haul in from deeper than this, the pulse pin goes silent for ever (a
    # cut wire: the encoder dies on the way up, the drum turns on).
    encoder_dead_in_from_m: float | None = None
    overcurrent_a: float | None = None  # the motor draws this whenever it runs
    current_adc: float | None = None  # the current sensor's ADC stuck here (0..1): a bad sensor
    storm_at_m: float | None = None  # past here going out, the pulse pin babbles from then on
    # With the motor running, the current sensor's ADC reads random values from a
    # generator seeded with this (the motor's noise on a long unshielded sensor wire).
    current_noise_seed: int | None = None
    supply_v: float | None = None  # the supply reads this, volts (a flat battery, a bad divider)


def _state_at(pin: Any, t: float, since: float) -> Any:
    """A mock pin's state at monotonic time `t`, from its record of changes (gpiozero's
    `states`: each the time since the one before, the last at `_last_change`); its state
    now if it changed at or after `since`, or if its record is not one to read."""
    last, now_state = pin._last_change, pin.state
    if last >= since or t >= last:
        return now_state
    states = list(pin.states)  # a snapshot: another thread may append as we read
    at = last
    for state in reversed(states[1:]):
        if t >= at:
            return state.state
        at -= state.timestamp
    return states[0].state if states else now_state


class SimulatedDrum:
    def __init__(
        self,
        factory: MockFactory,
        cfg: WinchGpioSettings,
        *,
        full_speed_m_s: float = 0.5,
        line_m: float = 0.0,
        faults: DrumFaults | None = None,
        running_current_a: float = 1.2,
        supply_v: float = 12.0,
        step_s: float = 0.001,
    ) -> None:
        self.cfg = cfg
        self.factory = factory
        self.drum = Drum(cfg.pulses_per_rev, cfg.drum_diameter_m)
        self.full_speed_m_s = full_speed_m_s
        self.faults = faults or DrumFaults()
        self.running_current_a = running_current_a
        self.supply_v = supply_v
        self.step_s = step_s
        self._line = line_m
        self.max_line_seen = line_m
        self.pulses_sent = 0
        self.encoder_dead = False  # the pulse pin silent for ever (encoder_dead_in_from_m)
        self._lock = threading.Lock()
        self._pay_out = factory.pin(cfg.payout_pin)
        self._haul_in = factory.pin(cfg.haulin_pin)
        self._enable = factory.pin(cfg.enable_pin, pin_class=MockPWMPin)
        self._switch = factory.pin(cfg.switch_pin)
        self._a = factory.pin(cfg.pulse_pin)
        self._b = factory.pin(cfg.encoder_b_pin) if cfg.counter == "quadrature" else None
        self._phase = math.floor(line_m / self.drum.metres_per_pulse)
        self._quad = 0
        self._switch_closed: bool | None = None
        self._current = CurrentSensor(cfg.adc_vref_v, cfg.current_zero_v, cfg.current_v_per_a)
        self._divider = VoltageDivider(cfg.adc_vref_v, cfg.divider_r1_ohm, cfg.divider_r2_ohm)
        self.adc = (
            _MockMCP3008(factory, 8 - cfg.adc_spi_device, self._adc_channel) if cfg.adc else None
        )
        self._noise: random.Random | None = None  # faults.current_noise_seed's, once used
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._moved_to = time.monotonic()  # the drum has moved as the motor ran until then

    @classmethod
    def factory_for(cls, cfg: WinchGpioSettings) -> MockWinchFactory:
        return MockWinchFactory({cfg.enable_pin})

    # ------------------------------------------------------------ observing

    @property
    def line_m(self) -> float:
        with self._lock:
            return self._line

    def motor(self) -> tuple[int, float]:
        """(direction -1/0/+1, duty) as the H-bridge pins say now."""
        duty = float(self._enable.state)
        out, into = bool(self._pay_out.state), bool(self._haul_in.state)
        if duty <= 0 or out == into:
            return 0, 0.0
        return (1 if out else -1), duty

    def motor_current_a(self) -> float:
        direction, duty = self.motor()
        if direction == 0:
            return 0.0
        if self.faults.overcurrent_a is not None:
            return self.faults.overcurrent_a
        if self._jammed(direction):
            return self.running_current_a * 4
        return self.running_current_a * duty

    # ------------------------------------------------------------ running

    def start(self) -> None:
        self.step(0.0)  # the switch's first state, before anyone moves
        self._thread = threading.Thread(target=self._run, name="simulated-drum", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        if self.adc is not None:
            self.adc.close()

    def _run(self) -> None:
        while not self._stop.wait(self.step_s):
            self.catch_up()

    def catch_up(self) -> None:
        """Move the drum over the time since it last moved (its thread does, every
        `step_s`; a test whose drum thread is closed may, to play a late thread)."""
        now = time.monotonic()
        self.step(now - self._moved_to)

    def step(self, dt: float) -> None:
        """Advance the drum over the last `dt` seconds as the motor really ran in them.

        On a loaded machine this thread can run late, by tens of milliseconds or more;
        a real drum does not wait for it. So each quarter pulse of line is moved at the
        H-bridge's state *at that moment*, from the mock pins' own record of their
        changes, and a change the winch makes while this step runs (a stop at a pulse
        it has just seen) holds from the pulse on, as it would have on time. A drum
        moved the whole `dt` at the state it read at the end went past the pulse at
        which the winch stopped it (1.155 m out against an end of line at 1.0 m) and
        misread a soft start, so the winch's dead reckoning looked wrong."""
        began = time.monotonic()
        self._moved_to = began
        if dt <= 0:
            self._advance(0.0, self.motor())  # the switch's state, nothing moved
            return
        quarter_s = self.drum.metres_per_pulse / 4 / max(self.full_speed_m_s, 1e-9)
        t = began - dt
        while t < began:
            sub = min(quarter_s, began - t)
            t += sub
            self._advance(sub, self._motor_at(t, since=began))

    def _motor_at(self, t: float, *, since: float) -> tuple[int, float]:
        """(direction, duty) as the pins stood at `t`; a pin changed at or after
        `since` (during this step: the winch reacting to a pulse of it) as it is now."""
        duty = float(_state_at(self._enable, t, since))
        out = bool(_state_at(self._pay_out, t, since))
        into = bool(_state_at(self._haul_in, t, since))
        if duty <= 0 or out == into:
            return 0, 0.0
        return (1 if out else -1), duty

    def _advance(self, dt: float, motor: tuple[int, float]) -> None:
        direction, duty = motor
        with self._lock:
            line = self._line
            if direction and not self._jammed(direction):
                line += direction * duty * self.full_speed_m_s * dt
            # The probe is up against the block. (With the switch stuck open the model
            # lets the line go below 0, a probe wound into the block; once mended, the
            # line is back at 0 without turning the drum: no pulses for that.)
            mended = self._line < 0.0 and not self.faults.switch_stuck_open
            if line < 0.0 and not self.faults.switch_stuck_open:
                line = 0.0
            dies = self.faults.encoder_dead_in_from_m
            if direction < 0 and dies is not None and self._line > dies:
                self.encoder_dead = True
            self._line = line
            self.max_line_seen = max(self.max_line_seen, line)
        storm = self.faults.storm_at_m
        if storm is not None and self.max_line_seen >= storm:
            for _ in range(STORM_PULSES_PER_STEP):  # a broken wire: pulses the drum never made
                self._pulse(1)
        phase = math.floor(line / self.drum.metres_per_pulse + 1e-9)
        if mended:
            self._phase = phase
        while phase != self._phase:
            step = 1 if phase > self._phase else -1
            self._phase += step
            self._pulse(step)
        self._drive_switch(line, direction)

    def _jammed(self, direction: int) -> bool:
        out, into = self.faults.jam_at_m, self.faults.jam_in_at_m
        if direction > 0:
            return out is not None and self._line >= out
        return into is not None and self._line <= into

    def _pulse(self, step: int) -> None:
        if self.encoder_dead:
            return  # the drum turns, the pin says nothing
        self.pulses_sent += 1
        lose = self.faults.lose_every
        if step > 0 and lose and self.pulses_sent % lose == 0:
            return
        if self._b is None:
            idle = self.cfg.pulse_pull == "up"  # pulled up: a pulse is a dip to low
            self._set(self._a, not idle)
            self._set(self._a, idle)
            return
        # Four transitions of the Gray code per step, forwards or backwards.
        for _ in range(4):
            self._quad = (self._quad + step) % 4
            a, b = _QUADRATURE[self._quad]
            self._set(self._a, not a)  # pulled up: idle high
            self._set(self._b, not b)

    def _drive_switch(self, line: float, direction: int) -> None:
        closed = line <= self.drum.metres_per_pulse / 4
        snag = self.faults.snag_at_m
        if snag is not None and direction > 0 and line >= snag:
            closed = True
        if self.faults.switch_stuck_open:
            closed = False
        if self.faults.switch_stuck_closed:
            closed = True
        if closed == self._switch_closed:
            return
        self._switch_closed = closed
        high = closed == (self.cfg.switch_active == "high")
        if self.cfg.switch_pull == "up":
            high = not closed
        elif self.cfg.switch_pull == "down":
            high = closed
        self._set(self._switch, high)

    @staticmethod
    def _set(pin: Any, high: bool) -> None:
        if high:
            pin.drive_high()
        else:
            pin.drive_low()

    def _adc_channel(self, channel: int) -> float:
        faults = self.faults
        if channel == self.cfg.current_channel:
            if faults.current_adc is not None:
                return faults.current_adc
            if faults.current_noise_seed is not None and self.motor()[0]:
                if self._noise is None:
                    self._noise = random.Random(faults.current_noise_seed)
                return self._noise.random()
            return current_fraction(self._current, self.motor_current_a())
        if channel == self.cfg.voltage_channel:
            supply = faults.supply_v if faults.supply_v is not None else self.supply_v
            return self._divider.fraction(supply)
        return 0.0


def mock_drum_for(settings: Settings) -> SimulatedDrum:
    """The drum behind `--winch gpio-mock`: the simulated winch's fault injection works
    on it too (--simulate --winch gpio-mock --winch-stall / --winch-fail-home)."""
    cfg = settings.winch.gpio
    sim = settings.winch.sim
    faults = DrumFaults(
        jam_at_m=sim.stall_at_m,
        jam_in_at_m=0.5 if sim.fail_home else None,
        switch_stuck_closed=sim.drum_fault == "switch-stuck",
        snag_at_m=SNAG_AT_M if sim.drum_fault == "snag" else None,
        current_adc=1.0 if sim.drum_fault == "adc-garbage" else None,
        storm_at_m=STORM_AT_M if sim.drum_fault == "pulse-storm" else None,
        encoder_dead_in_from_m=ENCODER_DEAD_FROM_M if sim.drum_fault == "encoder-dead" else None,
    )
    speed = cfg.line_speed_m_s / cfg.payout_duty
    return SimulatedDrum(SimulatedDrum.factory_for(cfg), cfg, full_speed_m_s=speed, faults=faults)
