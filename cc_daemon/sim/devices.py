"""The simulated devices the command line hands the daemon (`daemon.simulators`).

Each builder imports its simulator only when a backend asks for it, so a daemon
with real devices never loads the simulated sonde or gpiozero's mock pins.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from cc_daemon.config import Settings
from cc_daemon.daemon.simulators import Simulators, SondeSimulator

if TYPE_CHECKING:
    from cc_daemon.drivers.winch.factory import MockDrum


def _sonde(path: Path, line_out: Callable[[], float], settings: Settings) -> SondeSimulator:
    from cc_daemon.sim.sonde import SimulatedSonde

    sonde = settings.sonde
    return SimulatedSonde(
        path,
        line_out=line_out,
        parameters=sonde.parameters,
        slave_id=sonde.slave_id,
        baudrate=sonde.baudrate,
    )


def _drum(settings: Settings) -> MockDrum:
    from cc_daemon.sim.drum import mock_drum_for

    return mock_drum_for(settings)


SIMULATORS = Simulators(sonde=_sonde, drum=_drum)
