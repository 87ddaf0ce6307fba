"""The `cc-daemon` command line: the daemon itself and its tools.

    cc-daemon [--config PATH] [--port ...]   run the daemon (the systemd service)
    cc-daemon --simulate [...]               a whole survey against a simulated autopilot
    cc-daemon decode ...                     read frames: hex, a capture on stdin, a live port
    cc-daemon casts | export | plot          the survey journal
    cc-daemon snapshot DEST                  a consistent copy of the journal, even while running
    cc-daemon sonde export | plot            the sonde's readings and profiles
    cc-daemon simulate-autopilot --port P    the simulated autopilot alone, on a real port
    cc-daemon status [--json|--watch]        ask the running daemon what it is doing
    cc-daemon doctor                         check this Pi is ready to run the service
    cc-daemon simulate-sonde --port PATH     the simulated sonde alone, on a pty at PATH
    cc-daemon winch status|home|down|up      the GPIO winch by hand (jog, home, calibrate)
    cc-daemon simulate-sonar --port P        the simulated Ping1D echosounder alone
    cc-daemon web                            the field page: status and data in a browser

Exit status: 0 success; 1 a tool found problems (corrupt frames, a protocol
violation); 2 bad usage or configuration (nothing was opened); 3 a simulated
survey kept the protocol but left a station unmeasured; 130 the daemon was
stopped at once by a second Ctrl-C and the probe may be down.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from cc_daemon import __version__
from cc_daemon.cli.decode import (
    HexInputError,
    decode_chunks,
    parse_hex,
    print_events,
    read_stdin_chunks,
)
from cc_daemon.core.errors import ConfigError, WinchFault

EXIT_USAGE = 2


def _add_decode(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "decode",
        help="decode frames from hex arguments, stdin or a live serial port",
        description="Decode autopilot-link frames. Exit status 1 if any corrupt frame was found.",
    )
    p.add_argument("hex", nargs="*", help="frame bytes in hex, e.g. 50 53 00 48 00 EB")
    p.add_argument("--hex", dest="hex_stdin", action="store_true", help="stdin is hex text")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument("--accept-g-alias", action="store_true", help="decode P-G as start measuring")
    p.add_argument("--port", help="decode a live serial line until Ctrl-C")
    p.add_argument("--baudrate", type=int, help="baud rate for --port (9600)")
    p.add_argument(
        "--shared",
        action="store_true",
        help="with --port: read even if another process has the port open (each byte goes "
        "to one reader only: it steals that process's frames)",
    )
    p.set_defaults(handler=_run_decode)


def _run_decode(args: argparse.Namespace) -> int:
    from cc_daemon.cli.decode import (
        HEX_SNIFF_BYTES,
        checked_baudrate,
        keeping_head,
        looks_like_hex,
        summary_line,
        usage_problem,
    )
    from cc_daemon.core.protocol import Parser, Sender
    from cc_daemon.ground.logsetup import configure_logging

    # Decoded lines own stdout (it may be piped into jq); diagnostics go to stderr.
    configure_logging("auto", "warning", sys.stderr)
    problem = usage_problem(args)
    if problem is not None:
        print(f"cc-daemon decode: {problem}", file=sys.stderr)
        return EXIT_USAGE
    try:
        if args.port:
            from cc_daemon.cli.live_decode import decode_port

            baudrate = checked_baudrate(args.baudrate)
            return decode_port(
                args.port,
                baudrate,
                as_json=args.json,
                accept_g_alias=args.accept_g_alias,
                shared=args.shared,
            )
        chunks: Iterable[bytes]
        head = bytearray()
        if args.hex:
            chunks = [parse_hex(" ".join(args.hex))]
        else:
            if sys.stdin.isatty():  # a person at a terminal, not a pipe: say what we wait for
                print(
                    "cc-daemon decode: reading hex or bytes from standard input "
                    "(Ctrl-D to end, Ctrl-C to stop)",
                    file=sys.stderr,
                    flush=True,
                )
            raw = read_stdin_chunks(sys.stdin.buffer, hex_text=args.hex_stdin)
            chunks = raw if args.hex_stdin else keeping_head(raw, head, HEX_SNIFF_BYTES)
        parser = Parser(Sender.BOTH, accept_g_alias=args.accept_g_alias)
        status = print_events(decode_chunks(chunks, parser=parser), as_json=args.json)
        stats = parser.stats
        print(summary_line(stats), file=sys.stderr)
        if stats.frames_decoded == 0 and not stats.errors and looks_like_hex(bytes(head)):
            print(
                f"cc-daemon decode: 0 frames in {stats.bytes_received} bytes; "
                "this looks like hex text: use --hex",
                file=sys.stderr,
            )
            return EXIT_USAGE
        return status
    except HexInputError as exc:
        print(f"cc-daemon decode: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        # The reader of our stdout left (`| head -1`): not an error. Point stdout
        # at /dev/null so the interpreter's final flush does not complain.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def _add_daemon_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("daemon options (flags override env and file)")
    group.add_argument("--config", type=Path, help="TOML configuration file")
    group.add_argument("--port", help="serial port to the autopilot [serial.port]")
    group.add_argument("--baudrate", type=int, help="[serial.baudrate]")
    group.add_argument(
        "--winch",
        choices=["sim", "gpio", "gpio-mock"],
        help="winch backend [winch.backend]; gpio-mock: the GPIO winch on mock pins "
        '[winch.gpio.pin_factory = "mock"]',
    )
    group.add_argument("--db", type=Path, help="survey journal file [store.path]")
    group.add_argument("--log-format", choices=["console", "json"], help="[log.format]")
    group.add_argument(
        "--log-level",
        choices=["debug", "info", "warning", "error", "critical"],
        help="[log.level]",
    )


def flag_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The daemon flags as a nested settings dict (unset flags left out)."""
    winch: dict[str, Any] = {"backend": args.winch}
    if args.winch == "gpio-mock":  # one flag for two keys: the GPIO winch on mock pins
        winch = {"backend": "gpio", "gpio": {"pin_factory": "mock"}}
    return {
        "serial": {"port": args.port, "baudrate": args.baudrate},
        "winch": winch,
        "store": {"path": args.db},
        "log": {"format": args.log_format, "level": args.log_level},
    }


def build_parser() -> argparse.ArgumentParser:
    from cc_daemon.cli import data as datacli
    from cc_daemon.cli import sonde as sondecli
    from cc_daemon.cli import winch as winchcli
    from cc_daemon.cli.doctor import command as doctor_cli
    from cc_daemon.cli.parser import HintingParser
    from cc_daemon.cli.status import command as status_cli
    from cc_daemon.cli.web import command as web_cli
    from cc_daemon.sim import commands as simulator
    from cc_daemon.sim import sonar_cli
    from cc_daemon.sim import sondecli as simulate_sonde

    parser: argparse.ArgumentParser = HintingParser(
        prog="cc-daemon",
        description="Companion-computer daemon of an autonomous survey boat.",
        epilog="Run without a command to start the daemon.",
    )
    parser.add_argument("--version", action="version", version=f"cc-daemon {__version__}")
    parser.add_argument(
        "--simulate",
        action="store_true",
        help="run a whole survey against a simulated autopilot over a pty pair",
    )
    _add_daemon_options(parser)
    simulator.add_simulate_arguments(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_decode(sub)
    datacli.add_commands(sub)
    simulator.add_commands(sub)
    status_cli.add_commands(sub)
    doctor_cli.add_commands(sub)
    sondecli.add_command(sub)
    simulate_sonde.add_command(sub)
    winchcli.add_command(sub)
    sonar_cli.add_commands(sub)
    web_cli.add_command(sub)
    return parser


def _load(args: argparse.Namespace) -> Any:
    from cc_daemon.config import load_settings

    return load_settings(args.config, flag_overrides(args))


def _configure_daemon_logging(settings: Any) -> None:
    from cc_daemon.ground.logsetup import configure_logging, flush_rate_limited, resolve_format

    flush_rate_limited(everything=True)  # a reconfiguration must not lose held-back counts
    # "auto" follows stdout: a terminal gets the console renderer, journald
    # (or a pipe, or a file) gets JSON lines. The log itself goes to stderr.
    configure_logging(resolve_format(settings.log.format, sys.stdout), settings.log.level)


def _run_daemon(args: argparse.Namespace) -> int:
    from cc_daemon.daemon.preflight import check_paths, open_journal
    from cc_daemon.daemon.reload import Reloader
    from cc_daemon.daemon.service import Daemon
    from cc_daemon.daemon.simgate import check_backend_allowed
    from cc_daemon.drivers.winch.factory import check_pin_library
    from cc_daemon.sim.devices import SIMULATORS

    # From the first moment: the SSH session that started us closing must not
    # kill us (and a reload sent before the loop runs is simply not needed).
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    settings = _load(args)
    check_paths(settings)  # a port or journal path that can never work: exit 2 now
    check_backend_allowed(settings)  # a simulated winch not asked for: exit 2, nothing opened
    check_pin_library(settings)  # no lgpio for a GPIO winch: exit 1 before the journal exists
    _configure_daemon_logging(settings)
    daemon = Daemon(settings, journal=open_journal(settings), simulators=SIMULATORS)
    reloader = Reloader(daemon, lambda: _load(args), _configure_daemon_logging)
    try:
        return asyncio.run(_serve(daemon, reloader))
    finally:
        # Closing the loop gave SIGHUP its default (fatal) action back.
        signal.signal(signal.SIGHUP, signal.SIG_IGN)


async def _serve(daemon: Any, reload: Callable[[], None] | None = None) -> int:
    import structlog

    log = structlog.get_logger("cc_daemon.cli")
    loop = asyncio.get_running_loop()
    received: list[signal.Signals] = []

    def on_signal(signum: signal.Signals) -> None:
        received.append(signum)
        if len(received) == 1:
            log.info("signal received: bringing the probe home, then exiting", signal=signum.name)
            daemon.request_shutdown()
        elif signum is signal.SIGINT and signal.SIGINT in received[:-1]:
            # A person pressing Ctrl-C twice means it: stop the motor, exit now.
            log.warning("second Ctrl-C: stopping at once", signal=signum.name)
            daemon.request_shutdown(immediate=True)
        else:
            # A supervisor repeating SIGTERM must not abandon the probe.
            log.info("already shutting down; Ctrl-C twice stops at once", signal=signum.name)

    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, on_signal, signum)
    # SIGHUP (systemctl reload, or the terminal that started us closing) re-reads
    # the configuration; it never stops the daemon nor interrupts a cast.
    loop.add_signal_handler(signal.SIGHUP, reload or _ignore_hangup)
    code: int = await daemon.run()
    return code


def _simulate_only_options(
    parser: argparse.ArgumentParser, args: argparse.Namespace, argv: Sequence[str]
) -> list[str]:
    """The --simulate options given without --simulate (they would be ignored).

    Looked for among the words before the command, if any: a command may have an
    option of the same name (`simulate-sonde --seed`) that is its own.
    """
    words = list(argv)
    if args.command is not None and args.command in words:
        words = words[: words.index(args.command)]
    given: list[str] = []
    for group in parser._action_groups:
        if group.title != "--simulate options":
            continue
        for action in group._group_actions:
            if any(
                word == option or word.startswith(option + "=")
                for option in action.option_strings
                for word in words
            ):
                given.append(action.option_strings[0])
    return given


def _ignore_hangup() -> None:
    import structlog

    structlog.get_logger("cc_daemon.cli").info("SIGHUP ignored: nothing to reload")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    words = sys.argv[1:] if argv is None else argv
    stray = [] if args.simulate else _simulate_only_options(parser, args, words)
    if stray:
        print(f"cc-daemon: {', '.join(stray)} applies only with --simulate", file=sys.stderr)
        return EXIT_USAGE
    try:
        handler = getattr(args, "handler", None)
        if handler is not None:
            code: int = handler(args)
            return code
        if args.simulate:
            from cc_daemon.sim.commands import run_from_args

            return run_from_args(args, _load(args))
        return _run_daemon(args)
    except ConfigError as exc:
        print(str(exc), file=sys.stderr)
        return EXIT_USAGE
    except WinchFault as exc:  # the winch's pins cannot be opened: nothing to drive
        print(f"cc-daemon: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
