"""The simulated devices the edge hands the daemon.

A backend set to a simulated device (`sonde.backend = "sim"`, the GPIO winch on
gpiozero's mock pins) needs a simulated world behind it. The daemon never
imports the simulator: the command that builds the daemon (`cc-daemon`,
`--simulate`, the tests) passes these builders in, and a daemon given none
refuses such a backend with one line.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from cc_daemon.config import Settings
from cc_daemon.drivers.winch.factory import MockDrum


class SondeSimulator(Protocol):
    """A simulated Modbus sonde answering on a pty at `path`."""

    path: Path

    def start(self) -> None: ...

    def stop(self) -> None: ...


# (the pty path to serve, the line out now, the settings) -> a sonde not yet started
SondeSimulatorFactory = Callable[[Path, Callable[[], float], Settings], SondeSimulator]
MockDrumFactory = Callable[[Settings], MockDrum]


@dataclass(frozen=True, slots=True)
class Simulators:
    sonde: SondeSimulatorFactory | None = None
    drum: MockDrumFactory | None = None


NO_SIMULATORS = Simulators()
