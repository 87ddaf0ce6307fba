"""`cc-daemon winch`: drive the GPIO winch by hand, to jog it, home it and calibrate it.

It owns the command's options and what it prints: the line out, the pulse
count, the limit switch and (with the ADC) the motor current and supply
voltage, twice a second while the motor runs. It builds the winch exactly as
the daemon does (`winch.factory`), so every safety rule holds, and it leaves
the motor stopped however it ends (Ctrl-C, SIGTERM, an error). It never talks
to the autopilot and never writes the journal; the daemon must not be running
(the pins have one owner), except for `home`: with the daemon running it asks
the daemon (its control socket) to haul a stranded probe in.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import sys
from pathlib import Path
from typing import Any, TextIO

EXIT_OK = 0
EXIT_FAULT = 1
EXIT_USAGE = 2
PRINT_EVERY_S = 0.5


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "winch",
        help="jog, home and calibrate the GPIO winch by hand (stop the daemon first)",
        description="Drive the GPIO winch ([winch.gpio]) by hand and print the line out, "
        "the pulse count and the motor current. Exit status 1 on a winch fault.",
    )
    p.add_argument("action", choices=("status", "home", "down", "up"), help="what to do")
    p.add_argument("--config", type=Path, help="TOML configuration file")
    p.add_argument(
        "--db", type=Path, help="home: the journal of a daemon started by hand with --db"
    )
    amount = p.add_mutually_exclusive_group()
    amount.add_argument("--seconds", type=float, metavar="S", help="run for S seconds (5)")
    amount.add_argument("--metres", type=float, metavar="M", help="run for M metres of line")
    p.add_argument(
        "--mock", action="store_true", help="mock pins and a simulated drum (try it on a laptop)"
    )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from cc_daemon.config import load_settings
    from cc_daemon.ground.logsetup import configure_logging

    overrides: dict[str, Any] = {"winch": {"backend": "gpio"}}
    if args.db is not None:
        overrides["store"] = {"path": args.db}
    if args.mock:
        overrides["winch"]["gpio"] = {"pin_factory": "mock"}
    settings = load_settings(args.config, overrides)
    configure_logging("console", "info", sys.stderr)
    for name, value in (("--seconds", args.seconds), ("--metres", args.metres)):
        if value is not None and not value > 0:
            print(f"cc-daemon winch: {name} {value:g}: allowed > 0", file=sys.stderr)
            return EXIT_USAGE
    if args.action in ("status", "home") and (args.seconds or args.metres):
        print(f"cc-daemon winch {args.action}: takes no --seconds/--metres", file=sys.stderr)
        return EXIT_USAGE
    if args.action == "home":
        through = _home_through_daemon(settings)
        if through is not None:
            return through
    return asyncio.run(_drive(settings, args.action, args.seconds, args.metres, sys.stdout))


def _home_through_daemon(settings: Any) -> int | None:
    """With the daemon running (its control socket answers), it owns the pins: ask
    it to haul a stranded probe in. None: no daemon listens, drive the winch here.

    Only a socket that is not there, or that nobody listens on, means no daemon. A
    refusal (permission denied, not authorised, a socket someone else answers, no
    answer in time) means a daemon may be running: the winch is left to it, never
    driven by a second owner of its motor."""
    from cc_daemon.cli.daemon_socket import NoDaemon, SocketTrouble
    from cc_daemon.cli.release import ask_daemon, control_socket

    path = control_socket(settings, None)
    try:
        ok, message = ask_daemon(path, b"home")
    except NoDaemon:
        return None
    except SocketTrouble as exc:
        print(
            f"cc-daemon winch home: {exc}; the winch was not driven (a daemon may own it)",
            file=sys.stderr,
        )
        return EXIT_FAULT
    print(f"cc-daemon winch home (through the running daemon): {message}")
    return EXIT_OK if ok else EXIT_FAULT


def _line(winch: Any, cfg: Any) -> str:
    from cc_daemon.core.winch.sensors import supply_fault

    status = winch.status()
    parts = [
        f"line out {winch.line_m:7.3f} m",
        f"count {winch.pulse_count:5d}",
        f"switch {'closed' if winch.switch_closed else 'open'}",
    ]
    current, supply = winch.motor_current_a(), winch.supply_v()
    if current is not None:
        parts.append(f"current {current:5.2f} A")
    if supply is not None:
        parts.append(f"supply {supply:5.2f} V")
        if supply_fault(supply, min_v=cfg.supply_min_v, max_v=cfg.supply_max_v):
            parts.append(
                f"(cannot be true: outside {cfg.supply_min_v:g} to {cfg.supply_max_v:g} V)"
            )
    if status.at_home:
        parts.append("home (count and switch agree)")
    if status.fault:
        parts.append(f"FAULT: {status.fault}")
    if winch.sensor_fault:
        parts.append(f"SENSOR FAULT (overcurrent by pulses only): {winch.sensor_fault}")
    return "  ".join(parts)


async def _drive(
    settings: Any, action: str, seconds: float | None, metres: float | None, out: TextIO
) -> int:
    from cc_daemon.core.errors import WinchFault
    from cc_daemon.drivers.winch.factory import make_winch
    from cc_daemon.drivers.winch.gpio import GpioWinch
    from cc_daemon.drivers.winch.motor import Direction
    from cc_daemon.ground.clock import SystemClock
    from cc_daemon.sim.devices import SIMULATORS

    try:
        winch = make_winch(settings, SystemClock(), mock_drum=SIMULATORS.drum)
    except WinchFault as exc:
        print(f"cc-daemon winch: {exc}", file=sys.stderr)
        return EXIT_FAULT
    assert isinstance(winch, GpioWinch)
    loop = asyncio.get_running_loop()
    interrupted = asyncio.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, interrupted.set)
    try:
        await asyncio.sleep(0.05)  # the switch's state, from the pins
        print(_line(winch, settings.winch.gpio), file=out, flush=True)
        if action == "status":
            return EXIT_OK
        run: asyncio.Future[Any]
        if action == "home":
            run = asyncio.ensure_future(winch.home(reason="operator: cc-daemon winch home"))
        else:
            direction = Direction.PAY_OUT if action == "down" else Direction.HAUL_IN
            winch.jog(direction, by_m=metres)
            run = asyncio.ensure_future(_run_for(winch, metres is None, seconds or 5.0))
        stop = asyncio.ensure_future(interrupted.wait())
        while not run.done():
            await asyncio.wait({run, stop}, timeout=PRINT_EVERY_S)
            print(_line(winch, settings.winch.gpio), file=out, flush=True)
            if stop.done():
                winch.stop()
                print("interrupted: motor stopped", file=out)
                break
        stop.cancel()
        await asyncio.wait({run})
        fault = winch.status().fault
        return EXIT_FAULT if fault else EXIT_OK
    finally:
        await winch.close()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(signum)


async def _run_for(winch: Any, timed: bool, seconds: float) -> None:
    """Until the motor stops by itself, and at most `seconds` when `timed`."""
    deadline = asyncio.get_running_loop().time() + seconds
    while winch.status().moving:
        left = deadline - asyncio.get_running_loop().time()
        if timed and left <= 0:
            winch.stop()
            break
        await winch.wait_change(max(min(left, 0.2), 0.01) if timed else 0.2)
