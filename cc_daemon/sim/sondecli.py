"""`cc-daemon simulate-sonde --port PATH`: the simulated sonde alone, until Ctrl-C.

This module owns the command's arguments and its run: a `SimulatedSonde` on a
pty whose symlink is PATH (point `sonde.port` of a daemon at it), with the
probe going up and down on a scripted line (or held at `--depth`) and optional
random faults. It never touches a journal.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

EXIT_USAGE = 2


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "simulate-sonde",
        help="the simulated sonde alone, a Modbus RTU server on a pty at --port",
        description="Serve the default register map from a simulated reservoir on a "
        "pseudo-terminal whose path is --port (a symlink), until Ctrl-C. Point a daemon's "
        'sonde.port at it with sonde.backend = "modbus".',
    )
    p.add_argument("--port", required=True, type=Path, help="path of the pty symlink to create")
    p.add_argument("--baudrate", type=int, default=9600, help="line pacing (9600)")
    p.add_argument("--slave-id", type=int, default=80, help="Modbus device id (80)")
    p.add_argument(
        "--depth", type=float, metavar="M", help="hold the probe at this line out (default: "
        "down to --max-depth and back up, 0.25 m/s, forever)",
    )  # fmt: skip
    p.add_argument("--max-depth", type=float, default=8.0, metavar="M", help="(8 m)")
    p.add_argument("--bottom", type=float, default=12.0, metavar="M", help="water depth (12 m)")
    p.add_argument(
        "--fault-rate", type=float, default=0.0, metavar="P",
        help="share of requests given a random fault: timeout, crc, nan, exception (0)",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="noise and faults seed (0)")
    p.set_defaults(handler=_handler)


def _handler(args: argparse.Namespace) -> int:
    import random

    from cc_daemon.sim.sonde import SimulatedSonde, yo_yo
    from cc_daemon.sim.water import SondeModel, WaterColumn

    if not 0.0 <= args.fault_rate <= 1.0:
        print("cc-daemon simulate-sonde: --fault-rate must be between 0 and 1", file=sys.stderr)
        return EXIT_USAGE
    if not 1 <= args.slave_id <= 247:
        print("cc-daemon simulate-sonde: --slave-id must be 1 to 247", file=sys.stderr)
        return EXIT_USAGE
    if args.port.exists() and not args.port.is_symlink():
        print(f"cc-daemon simulate-sonde: {args.port} exists and is not a symlink", file=sys.stderr)
        return EXIT_USAGE
    depth = args.depth
    line_out = (lambda: depth) if depth is not None else yo_yo(args.max_depth)
    model = SondeModel(WaterColumn(bottom_m=args.bottom), rng=random.Random(args.seed))
    sonde = SimulatedSonde(
        args.port,
        line_out=line_out,
        slave_id=args.slave_id,
        baudrate=args.baudrate,
        model=model,
        fault_rate=args.fault_rate,
        seed=args.seed,
    )
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    sonde.start()
    print(
        f"simulated sonde on {args.port} (slave {args.slave_id}, {args.baudrate} baud); "
        "Ctrl-C to stop",
        flush=True,
    )
    try:
        stop.wait()
    finally:
        sonde.stop()
    print(f"served {sonde.requests} requests, {sonde.faults_injected} with a fault", flush=True)
    return 0
