"""`cc-daemon simulate-sonar --port PATH`: the simulated Ping1D alone on a serial port.

This module owns that command: a mission's water under a boat holding still
at its first station (or drifting along its first transit with `--under-way`),
heard by the simulated Ping1D, served on PATH at 115200 8N1 until Ctrl-C or
SIGTERM: a serial port that exists is opened; where PATH does not exist (or is
a dangling symlink) a pseudo-terminal is created with PATH pointing at it, as
`simulate-sonde` does, for a daemon's `sonar.port` or brping's
`--device`. It prints one line when it is ready and one summary line at the end.
It never opens anything but PATH.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
import time
from pathlib import Path

from cc_daemon.sim.mission import Mission, Point, make_mission
from cc_daemon.sim.ping1d import FieldSounder, Ping1DDevice, Ping1DServer
from cc_daemon.sim.pty import PtyPair

EXIT_USAGE = 2
_DRIFT_M_S = 1.5


def add_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "simulate-sonar",
        help="the simulated Ping1D echosounder alone, on a serial port",
        description="Serve a simulated Blue Robotics Ping1D (ping protocol, 115200 8N1) on "
        "PATH: it answers general requests for protocol_version, device_id, speed_of_sound "
        "and distance_simple, and streams distance_simple every 250 ms between "
        "continuous_start and continuous_stop. Its readings come from a simulated mission's "
        "water depth. Stop it with Ctrl-C.",
    )
    p.add_argument(
        "--port",
        required=True,
        help="serial device, e.g. /dev/ttyUSB1; a path that does not exist becomes a pty symlink",
    )
    p.add_argument("--seed", type=int, default=1, help="mission and noise seed (1)")
    p.add_argument("--station", type=int, default=1, help="hold at this station (1)")
    p.add_argument(
        "--under-way", action="store_true", help="sail the transit to the station instead"
    )
    p.set_defaults(handler=_handler)


def _handler(args: argparse.Namespace) -> int:
    try:
        if args.station < 1:
            raise ValueError(f"--station {args.station}: allowed >= 1")
        mission = make_mission(args.station, args.seed)
        return asyncio.run(serve(args.port, mission, under_way=args.under_way, seed=args.seed))
    except (OSError, ValueError) as exc:  # no such port, permission, bad numbers
        print(f"cc-daemon simulate-sonar: {exc}", file=sys.stderr)
        return EXIT_USAGE


async def serve(port: str, mission: Mission, *, under_way: bool = False, seed: int = 1) -> int:
    """Serve until SIGINT or SIGTERM, over the last station of `mission`."""
    begin, station = mission.leg(len(mission.stations) - 1)
    started = time.monotonic()

    def where() -> tuple[Point, bool]:
        if not under_way:
            return station, False
        return begin.towards(station, (time.monotonic() - started) * _DRIFT_M_S), True

    sounder = FieldSounder(mission, where, seed=seed)
    pair = _pty_unless_present(Path(port))
    try:
        if pair is None:
            server = await Ping1DServer.over_serial(port, Ping1DDevice(sounder))
        else:
            server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(sounder))
    except BaseException:
        if pair is not None:
            pair.close()
        raise
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    print(
        f"simulated Ping1D on {port} at 115200 8N1: water {mission.field.depth_at(station):.2f} m",
        flush=True,
    )
    try:
        await stop.wait()
    finally:
        for signum in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(Exception):
                loop.remove_signal_handler(signum)
        await server.close()
        if pair is not None:
            pair.close()
    device = server.device
    print(
        f"simulated Ping1D stopped: {len(device.requests)} requests, "
        f"{device.sent_readings} readings sent, {device.bad_frames} bad frames",
        flush=True,
    )
    return 0


def _pty_unless_present(path: Path) -> PtyPair | None:
    """A pty with `path` pointing at it, unless a device is there (a dangling link is
    replaced)."""
    return None if path.exists() else PtyPair(path)
