"""Never a simulated cast recorded as real: which winches are simulated, and the gate.

It owns three answers: the name a winch backend is recorded under ("sim",
"gpio" or "gpio-mock"), whether data from it are simulated (no motor moved a
probe), and whether such a winch may run at all. Outside `--simulate` and the
tests a simulated winch would answer a real autopilot with depths and `R-F`
for a probe that never moved, so it runs only when
`winch.sim.allow_outside_simulation = true` says so in so many words, and then
the daemon says so at critical once and in every systemd STATUS.

It never opens a device and never exits: `check_backend_allowed` raises
ConfigError (the command line turns that into exit status 2).
"""

from __future__ import annotations

from cc_daemon.config import Settings
from cc_daemon.core.errors import ConfigError

_PREFIX = "cc-daemon: bad configuration: "


def backend_name(settings: Settings) -> str:
    """The backend as recorded in the journal and the exports."""
    winch = settings.winch
    if winch.backend == "gpio" and winch.gpio.pin_factory == "mock":
        return "gpio-mock"
    return winch.backend


def is_simulated(settings: Settings) -> bool:
    """True when no real motor moves: the data are not a real cast's."""
    return backend_name(settings) != "gpio"


def check_backend_allowed(settings: Settings) -> None:
    """The daemon outside --simulate: refuse a simulated winch not asked for by name."""
    if not is_simulated(settings) or settings.winch.sim.allow_outside_simulation:
        return
    # Named as every bad value is: its value and where it came from ("(default)" on a
    # laptop with no configuration file).
    if settings.winch.backend == "sim":
        chosen = settings.describe("winch.backend")
    else:
        chosen = (
            f"{settings.describe('winch.backend')} with "
            f"{settings.describe('winch.gpio.pin_factory')}"
        )
    raise ConfigError(
        f"{_PREFIX}{chosen}: a simulated winch would answer the autopilot for a probe that "
        "never moves; outside --simulate it runs only with "
        'winch.sim.allow_outside_simulation = true; on the boat set winch.backend = "gpio"; '
        "to try cc-daemon on this computer: cc-daemon --simulate"
    )


def simulation_warning(settings: Settings) -> str | None:
    """What a daemon running a simulated winch outside --simulate says: only when it
    was allowed explicitly (the gate refused it otherwise; None for a real winch)."""
    if not (is_simulated(settings) and settings.winch.sim.allow_outside_simulation):
        return None
    return (
        f"SIMULATED WINCH ({backend_name(settings)}): no probe moves; "
        "casts are journaled as simulated"
    )
