"""The simulator's command line: `--simulate`'s options and `simulate-autopilot`.

This module owns the argparse wiring and turning parsed arguments into options
and a finished run's exit status. It never runs anything itself beyond handing
the options to `runner`.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from typing import TYPE_CHECKING

from cc_daemon.sim.autopilot import FIRMWARES
from cc_daemon.sim.lines import DEFAULT_LINE_LENGTH_M, DEFAULT_LINES, DEFAULT_SPACING_M
from cc_daemon.sim.options import (
    FAST,
    PACES,
    PATTERNS,
    REALTIME,
    STALL_AT_M,
    AutopilotOnlyOptions,
    SimOptions,
)
from cc_daemon.sim.runner import run_autopilot, run_simulation
from cc_daemon.sim.summary import EXIT_STATUSES

if TYPE_CHECKING:
    from cc_daemon.config import Settings

EXIT_USAGE = 2


def _rate(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text}: a probability per byte, 0..1")
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text}: at least 1")
    return value


def _metres(text: str) -> float:
    value = float(text)
    if not 0 < value <= 10_000:
        raise argparse.ArgumentTypeError(f"{text}: metres, > 0 and at most 10000")
    return value


def _seconds(text: str) -> float:
    value = float(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"{text}: seconds, >= 0")
    return value


def _positive_seconds(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text}: seconds, > 0")
    return value


def _mission_arguments(group: argparse._ArgumentGroup) -> None:
    group.add_argument(
        "--stations", type=_count, default=3, metavar="N", help="stations to visit (3)"
    )
    group.add_argument(
        "--seed", type=int, default=1, metavar="S", help="mission and noise seed (1)"
    )
    group.add_argument(
        "--resend-m",
        action="store_true",
        help="keep resending M during each cast, as a flight plan that keeps the station "
        "selected does (the daemon must still cast once per station)",
    )
    group.add_argument(
        "--firmware",
        choices=FIRMWARES,
        default="ucm-2023",
        help="behave as the deployed 2023 firmware (26-byte M once, little-endian "
        "timestamps, T every 1.1 s, silence until R-F, a stick jog at the deepest station) "
        "or as the manual describes (default: ucm-2023)",
    )


def add_simulate_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `cc-daemon --simulate` (the daemon's own flags stay the parser's)."""
    group = parser.add_argument_group(
        "--simulate options",
        "A whole survey on this machine: the daemon against a simulated autopilot over a "
        "pty pair. The journal goes to --db (default ./simulate.db). " + EXIT_STATUSES,
    )
    _mission_arguments(group)
    group.add_argument(
        "--pace",
        choices=tuple(PACES),
        default=FAST.name,
        help="fast (the default): brisk transits, a 1.25 m/s winch and short dwells, "
        "overriding your cast settings (the header lists each change); real: a 1.5 m/s "
        "boat and your own winch and cast settings, unchanged (minutes per station)",
    )
    group.add_argument("--realtime", action="store_true", help="the same as --pace real")
    group.add_argument(
        "--corrupt",
        type=_rate,
        default=0.0,
        metavar="RATE",
        help="flip one bit in a byte on the link with this probability, both ways (e.g. "
        "0.02), never two bits within 25 bytes (the longest frame): every spoiled frame "
        "fails its checksum, as on a line whose checksum catches every error",
    )
    group.add_argument(
        "--drop-link-at",
        type=_seconds,
        metavar="T",
        help="pull the cable T seconds into the run, for --drop-link-for seconds",
    )
    group.add_argument(
        "--drop-link-for", type=_positive_seconds, default=3.0, metavar="S", help="(3 s)"
    )
    group.add_argument(
        "--winch-stall",
        action="store_true",
        help=f"the simulated winch stalls at {STALL_AT_M:g} m: casts abort and come home",
    )
    group.add_argument(
        "--winch-fail-home",
        action="store_true",
        help="the simulated winch jams on the way home: no R-F, the autopilot gives up",
    )
    group.add_argument(
        "--winch-fault",
        choices=("switch-stuck", "snag", "adc-garbage", "pulse-storm", "encoder-dead"),
        default="none",
        metavar="NAME",
        help="with --winch gpio-mock, a sensor fault on the mock drum: switch-stuck (closed: "
        "no R-F, stranded), snag (the switch closes at 1 m: stranded), adc-garbage (the "
        "current sensor at full scale: said once, casts go on), pulse-storm (the pulse pin "
        "babbles from 1 m down: an encoder fault, stranded), encoder-dead (the pulse pin "
        "dies on the first haul up from below 1 m: the motor current says the drum turned, "
        "the depth is dead-reckoned, stranded)",
    )
    group.add_argument(
        "--sonar-port",
        metavar="PATH",
        help="the autopilot reads a real Ping1D here (115200 8N1) instead of the simulated one",
    )
    group.add_argument(
        "--no-sonar", action="store_true", help="no Ping1D: the autopilot makes its readings up"
    )
    group.add_argument("--plain", action="store_true", help="plain log lines even on a terminal")
    group.add_argument(
        "--pattern",
        choices=PATTERNS,
        default="stations",
        help="stations (the default): a meandering transit from station to station; lines: "
        "parallel lines for bathymetry, sailed at 1.5 m/s whatever the pace, the stations "
        "spread along them (then `cc-daemon map`)",
    )
    group.add_argument(
        "--spacing", type=_metres, default=DEFAULT_SPACING_M, metavar="M",
        help=f"with --pattern lines: metres between lines ({DEFAULT_SPACING_M:g})",
    )  # fmt: skip
    group.add_argument(
        "--lines", type=_count, default=DEFAULT_LINES, metavar="N",
        help=f"with --pattern lines: how many ({DEFAULT_LINES})",
    )  # fmt: skip
    group.add_argument(
        "--line-length", type=_metres, default=DEFAULT_LINE_LENGTH_M, metavar="M",
        help=f"with --pattern lines: each line's length ({DEFAULT_LINE_LENGTH_M:g} m)",
    )  # fmt: skip


def options_from_args(args: argparse.Namespace, settings: Settings | None) -> SimOptions:
    winch = settings.winch if settings is not None else None
    mock = winch is not None and winch.backend == "gpio" and winch.gpio.pin_factory == "mock"
    if args.winch_fault != "none" and not mock:
        raise ValueError(f"--winch-fault {args.winch_fault}: applies only with --winch gpio-mock")
    return SimOptions(
        stations=args.stations,
        seed=args.seed,
        realtime=args.realtime or args.pace == REALTIME.name,
        corrupt=args.corrupt,
        drop_link_at=args.drop_link_at,
        drop_link_for=args.drop_link_for,
        winch_stall=args.winch_stall,
        winch_fail_home=args.winch_fail_home,
        winch_fault=args.winch_fault,
        resend_m=args.resend_m,
        firmware=args.firmware,
        db=getattr(args, "db", None),
        live=False if args.plain else None,
        settings=settings,
        sonar=not args.no_sonar,
        sonar_port=args.sonar_port,
        pattern=args.pattern,
        spacing_m=args.spacing,
        lines=args.lines,
        line_length_m=args.line_length,
    )


def run_from_args(args: argparse.Namespace, settings: Settings | None = None) -> int:
    """`cc-daemon --simulate ...`: parse-time options to a finished run's exit status."""
    try:
        options = options_from_args(args, settings)
        options.mission()  # a mission that cannot be laid out
    except ValueError as exc:
        print(f"cc-daemon --simulate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return asyncio.run(run_simulation(options))


def add_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `simulate-autopilot`."""
    p = sub.add_parser(
        "simulate-autopilot",
        help="the simulated autopilot alone, on a serial port (against a daemon elsewhere)",
        description="Run the simulated autopilot on a real serial port, e.g. a USB-serial "
        "cable to a Raspberry Pi running cc-daemon. " + EXIT_STATUSES,
    )
    p.add_argument("--port", required=True, help="serial device, e.g. /dev/ttyUSB0")
    p.add_argument("--baudrate", type=int, default=9600, help="(9600, 8N1)")
    group = p.add_argument_group("mission")
    _mission_arguments(group)
    group.add_argument(
        "--frame-period",
        type=float,
        default=None,
        metavar="S",
        help="seconds per frame (1.1 for ucm-2023, 1 for manual)",
    )
    group.add_argument(
        "--boat-speed", type=float, default=1.5, metavar="M_S", help="transit speed (1.5 m/s)"
    )
    group.add_argument(
        "--finish-timeout",
        type=float,
        default=900.0,
        metavar="S",
        help="give up on a station after this long without R-F (900 s)",
    )
    group.add_argument(
        "--no-plan-check",
        action="store_true",
        help="do not expect the daemon's default plan (the shoal refused, the rest cast)",
    )
    group.add_argument("--plain", action="store_true", help="plain log lines even on a terminal")
    p.set_defaults(handler=_autopilot_handler)


def _autopilot_handler(args: argparse.Namespace) -> int:
    try:
        options = AutopilotOnlyOptions(
            port=args.port,
            baudrate=args.baudrate,
            stations=args.stations,
            seed=args.seed,
            frame_period_s=args.frame_period,
            boat_speed_m_s=args.boat_speed,
            resend_m=args.resend_m,
            firmware=args.firmware,
            check_plan=not args.no_plan_check,
            finish_timeout_s=args.finish_timeout,
            live=False if args.plain else None,
        )
        return asyncio.run(run_autopilot(options))
    except (OSError, ValueError) as exc:  # no such port, permission, bad numbers
        print(f"cc-daemon simulate-autopilot: {exc}", file=sys.stderr)
        return EXIT_USAGE
