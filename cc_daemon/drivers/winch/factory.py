"""Which winch the daemon drives, built from `[winch]`.

It owns choosing and building the backend (the simulated winch, the GPIO winch
on the Pi's pins, or the GPIO winch on gpiozero's mock pins with a simulated
drum) and the start-up step a backend needs before casts (homing). Whether a
simulated one may run is `cc_daemon.daemon.simgate`'s rule. It never runs a motion.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, Protocol

import structlog

from cc_daemon.config import Settings
from cc_daemon.core.errors import WinchFault
from cc_daemon.core.winch.physics import LinePhysics
from cc_daemon.core.winch.status import Winch
from cc_daemon.drivers.winch.simulated import SimulatedWinch
from cc_daemon.ground.clock import Clock

_log = structlog.get_logger("cc_daemon.winch")


class MockDrum(Protocol):
    """A simulated drum behind gpiozero's mock pins; the simulator provides one."""

    factory: Any  # the pin factory the winch's devices open on

    def start(self) -> None: ...

    def close(self) -> None: ...


def make_winch(
    settings: Settings,
    clock: Clock,
    *,
    record: Callable[..., None] | None = None,
    mock_drum: Callable[[Settings], MockDrum] | None = None,
) -> Winch:
    """The configured winch backend. The GPIO ones need a running event loop; the mock
    pins need `mock_drum`, the simulated drum the edge hands in."""
    winch = settings.winch
    if winch.backend == "sim":
        physics = LinePhysics(
            speed_m_s=winch.sim.speed_m_s,
            max_line_m=winch.max_line_m,
            stall_at_m=winch.sim.stall_at_m,
            fail_home=winch.sim.fail_home,
        )
        return SimulatedWinch(physics, clock)
    return _make_gpio(settings, clock, record, mock_drum)


def _make_gpio(
    settings: Settings,
    clock: Clock,
    record: Callable[..., None] | None,
    mock_drum: Callable[[Settings], MockDrum] | None,
) -> Winch:
    from cc_daemon.drivers.winch.devices import open_devices
    from cc_daemon.drivers.winch.gpio import GpioWinch

    cfg = settings.winch.gpio
    on_close: Callable[[], None] | None = None
    factory: Any
    if cfg.pin_factory == "mock":
        if mock_drum is None:
            raise WinchFault(
                'winch.gpio.pin_factory = "mock" needs the simulated drum, which only the '
                "simulator and the cc-daemon command provide"
            )
        drum = mock_drum(settings)
        factory = drum.factory
        on_close = drum.close
    else:
        factory = native_pin_factory()
    try:
        devices = open_devices(cfg, factory)
    except Exception as exc:
        raise WinchFault(f"cannot open the winch's GPIO pins: {type(exc).__name__}: {exc}") from exc
    gpio = GpioWinch(
        cfg,
        devices,
        max_line_m=settings.winch.max_line_m,
        clock=clock,
        record=record,
        on_close=on_close,
    )
    if cfg.pin_factory == "mock":
        drum.start()
    return gpio


LGPIO_MISSING = (
    "cannot drive the GPIO winch: the lgpio library is missing "
    "(sudo make install installs it for a GPIO configuration; in a venv: "
    "pip install 'cc-daemon[pi]')"
)


def check_pin_library(settings: Settings) -> None:
    """WinchFault now if the configured winch needs lgpio and it is not installed:
    checked before anything is created (the journal) or opened, without importing it."""
    from importlib.util import find_spec

    native = settings.winch.backend == "gpio" and settings.winch.gpio.pin_factory == "native"
    if native and find_spec("lgpio") is None:
        raise WinchFault(LGPIO_MISSING)


def native_pin_factory() -> Any:
    """gpiozero's lgpio factory (Raspberry Pi OS Bookworm, Pi 4 and Pi 5), never set globally."""
    try:
        from gpiozero.pins.lgpio import LGPIOFactory
    except ImportError as exc:
        raise WinchFault(LGPIO_MISSING) from exc
    try:
        return LGPIOFactory()
    except Exception as exc:
        raise WinchFault(
            f"cannot open the Pi's GPIO chip: {type(exc).__name__}: {exc} "
            "(is this a Raspberry Pi, and is the user in the gpio group?)"
        ) from exc


async def prepare_winch(
    winch: Winch, announce: Callable[[], None] | None = None, left_down_m: float | None = None
) -> None:
    """What a backend must do before casts are accepted: the GPIO winch homes a probe
    found down (`announce` is called first, to say so); `left_down_m`, the depth a
    cast the previous run died in last journaled, is where its probe may still be."""
    # A GpioWinch exists only if its module was imported: asking `sys.modules` spares
    # the simulated winch importing gpiozero (33 ms, 2 MiB) for an isinstance check.
    gpio = sys.modules.get("cc_daemon.drivers.winch.gpio")
    if gpio is not None and isinstance(winch, gpio.GpioWinch):
        # The switch alone: a probe whose switch is open is surely down.
        if not winch.switch_closed and announce is not None:
            announce()
        await winch.start_up(left_down_m)


def hand_move(winch: Winch, depth_m: float) -> None:
    """An operator's move (the RC stick's jog): the GPIO winch takes it even while its
    witnesses disagree (docs/gpio-winch.md); any other backend moves as ever."""
    gpio = sys.modules.get("cc_daemon.drivers.winch.gpio")  # see prepare_winch
    if gpio is not None and isinstance(winch, gpio.GpioWinch):
        winch.hand_move(depth_m)
    else:
        winch.move_to(depth_m)
