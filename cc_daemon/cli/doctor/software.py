"""The doctor's software checks: is every library the configuration uses installed,
and does the winch that answers the autopilot move a real probe?

A check per piece the configuration in force needs: lgpio for the GPIO winch on
the Pi's pins, pymodbus for a sonde, brping for the sonar, matplotlib and
netCDF4 for `plot` and `export --format netcdf` (a WARN: the service runs
without them); and a WARN when the field page listens beyond this Pi without a
password. Libraries are looked up, never imported, so the doctor stays
quick and a broken library cannot take it down.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Callable, Iterator

from cc_daemon.cli.doctor.verdict import Check
from cc_daemon.config import Settings
from cc_daemon.daemon.simgate import backend_name, is_simulated

REINSTALL = "sudo make install (the installer installs what the configuration uses)"


def check_software(settings: Settings, found: Callable[[str], bool]) -> Iterator[Check]:
    """`found(module)`: is that library installed (`System.installed`)."""
    winch = settings.winch
    if winch.backend == "gpio" and winch.gpio.pin_factory == "native":
        if found("lgpio"):
            yield Check("lgpio", "OK", "installed: the GPIO winch can open the Pi's pins")
        else:
            yield Check(
                "lgpio",
                "FAIL",
                'winch.backend = "gpio" needs the lgpio library, not installed in this venv',
                "pip install 'cc-daemon[pi]' in the service's venv, or " + REINSTALL,
            )
    if is_simulated(settings):
        name = backend_name(settings)
        if winch.sim.allow_outside_simulation:
            yield Check(
                "winch",
                "WARN",
                f"a simulated winch ({name}) answers the autopilot: no probe moves, "
                "casts are journaled as simulated",
                'on the boat: winch.backend = "gpio" and '
                "winch.sim.allow_outside_simulation = false",
            )
        else:
            yield Check(
                "winch",
                "FAIL",
                f"a simulated winch ({name}) is configured: the daemon refuses to start",
                'on the boat: winch.backend = "gpio"',
            )
    if settings.sonde.backend != "none":
        yield _library("pymodbus", found, f'sonde.backend = "{settings.sonde.backend}"')
    if settings.sonar.port is not None:
        yield _library("brping", found, "sonar.port is set")
    missing = [name for name in ("matplotlib", "netCDF4") if not found(name)]
    if missing:
        yield Check(
            "plots and NetCDF",
            "WARN",
            f"{' and '.join(missing)} not installed: `plot` and `export --format netcdf` "
            "will not run here (the service does not need them)",
            "pip install 'cc-daemon[plot,netcdf]' in the venv, or " + REINSTALL,
        )
    else:
        yield Check("plots and NetCDF", "OK", "matplotlib and netCDF4 installed")
    yield from check_web(settings)


def _loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return host == "localhost"


def check_web(settings: Settings) -> Iterator[Check]:
    """The field page beyond this Pi: said, and a WARN without a password. Nothing
    to say when it listens on localhost (the default)."""
    listen = settings.web.listen
    host = listen.rpartition(":")[0]
    if _loopback(host):
        return
    if settings.web.password_hash:
        yield Check("field page", "OK", f"web.listen = {listen}, with a password")
        return
    yield Check(
        "field page",
        "WARN",
        f"web.listen = {listen} reaches beyond this Pi with no password: anyone on the "
        "boat's network can read the page and download the surveys",
        "cc-daemon web --hash-password, then put the line it prints under [web], "
        'or web.listen = "127.0.0.1:8080"',
    )


def _library(module: str, found: Callable[[str], bool], because: str) -> Check:
    if found(module):
        return Check(module, "OK", f"installed ({because})")
    return Check(module, "FAIL", f"{because} needs {module}, not installed", REINSTALL)
