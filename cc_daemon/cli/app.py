"""The `cc-daemon` command line: the daemon itself and its tools.

    cc-daemon [--config PATH] [--port ...]   run the daemon (the systemd service)
    cc-daemon --simulate [...]               a whole survey against a simulated autopilot
    cc-daemon decode ...                     read frames: hex, a capture on stdin, a live port
    cc-daemon casts | export | plot          the survey journal
    cc-daemon snapshot DEST                  a consistent copy of the journal, even while running
    cc-daemon sonde export | plot            the sonde's readings and profiles
    cc-daemon profiles -o DIR                binned profiles, stations, plots, sections
    cc-daemon simulate-autopilot --port P    the simulated autopilot alone, on a real port
    cc-daemon status [--json|--watch]        ask the running daemon what it is doing
    cc-daemon doctor                         check this Pi is ready to run the service
    cc-daemon simulate-sonde --port PATH     the simulated sonde alone, on a pty at PATH
    cc-daemon winch status|home|down|up      the GPIO winch by hand (jog, home, calibrate)
    cc-daemon release --reason TEXT          release a stranded station (probe seen on board)
    cc-daemon simulate-sonar --port P        the simulated Ping1D echosounder alone
    cc-daemon web                            the field page: status and data in a browser

Exit status: 0 success; 1 a tool found problems (corrupt frames, a protocol
violation); 2 bad usage or configuration (nothing was opened); 3 a simulated
survey kept the protocol but left a station unmeasured; 130 the daemon was
stopped at once by a second Ctrl-C and the probe may be down.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from cc_daemon import __version__
from cc_daemon.cli.output import guarded
from cc_daemon.core.errors import ConfigError, WinchFault
from cc_daemon.ground.signals import SignalHold

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
        HexInputError,
        checked_baudrate,
        decode_chunks,
        keeping_head,
        looks_like_hex,
        parse_hex,
        print_events,
        read_stdin_chunks,
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


# Each command's module, imported only when that command runs (or for --help): the
# daemon itself imports none of them (docs/performance.md). Order: the --help listing.
_COMMANDS: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (("casts", "export", "plot", "snapshot", "surveys"), "cc_daemon.cli.data", "add_commands"),
    (("simulate-autopilot",), "cc_daemon.sim.commands", "add_commands"),
    (("status",), "cc_daemon.cli.status.command", "add_commands"),
    (("doctor",), "cc_daemon.cli.doctor.command", "add_commands"),
    (("sonde",), "cc_daemon.cli.sonde", "add_command"),
    (("profiles",), "cc_daemon.cli.profiles", "add_command"),
    (("simulate-sonde",), "cc_daemon.sim.sondecli", "add_command"),
    (("winch",), "cc_daemon.cli.winch", "add_command"),
    (("release",), "cc_daemon.cli.release", "add_command"),
    (("recover",), "cc_daemon.cli.recover", "add_command"),
    (("web",), "cc_daemon.cli.web.command", "add_command"),
    (("simulate-sonar",), "cc_daemon.sim.sonar_cli", "add_commands"),
    (("map",), "cc_daemon.cli.mapcmd", "add_command"),
)
_HELP = ("-h", "--help")


def build_parser(
    command: str | None = "*", *, simulate: bool = True, exit_on_error: bool = True
) -> argparse.ArgumentParser:
    """The command line. `command`: the one command whose module is imported and whose
    options are registered (`"*"`: all of them, for --help); every other command is a
    bare name, enough to be recognised. `simulate`: register the --simulate options
    (they live with the simulator)."""
    from cc_daemon.cli.parser import HintingParser

    parser: argparse.ArgumentParser = HintingParser(
        prog="cc-daemon",
        description="Companion-computer daemon of an autonomous survey boat.",
        epilog="Run without a command to start the daemon.",
        exit_on_error=exit_on_error,
    )
    parser.add_argument("--version", action="version", version=f"cc-daemon {__version__}")
    parser.add_argument(
        "--simulate",
        action="store_true",
        help="run a whole survey against a simulated autopilot over a pty pair",
    )
    _add_daemon_options(parser)
    if simulate:
        from cc_daemon.sim.commands import add_simulate_arguments

        add_simulate_arguments(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    if command in ("*", "decode"):
        _add_decode(sub)
    else:
        sub.add_parser("decode", add_help=False)
    for names, module, register in _COMMANDS:
        if command == "*" or command in names:
            getattr(importlib.import_module(module), register)(sub)
        else:
            for name in names:
                sub.add_parser(name, add_help=False)
    return parser


def parse_command_line(argv: Sequence[str]) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and the arguments, importing no more than the run needs.

    A first pass, with every command a bare name and no --simulate options, finds
    the command. The daemon's own run (no command, no --simulate, every word known)
    stops there; a command is parsed again with its own options; anything the first
    pass cannot read (--help, a stray option, a typo) by the whole parser, as ever.
    """
    words = list(argv)
    if not any(word in _HELP for word in words):
        first = build_parser(None, simulate=False, exit_on_error=False)
        try:
            args, extra = first.parse_known_args(words)
        except argparse.ArgumentError:
            pass  # the whole parser below says what is wrong, in its words
        else:
            if args.command is None and not args.simulate and not extra:
                return first, args
            command = args.command
            before = words[: words.index(command)] if command in words else words
            # A command's run has no use for the --simulate options (nor their import),
            # unless one was given before it: then the error names it (`main`).
            simulate = command is None or args.simulate or any(w in extra for w in before)
            parser = build_parser(command, simulate=simulate)
            return parser, parser.parse_args(words)
    parser = build_parser()
    return parser, parser.parse_args(words)


def _load(args: argparse.Namespace) -> Any:
    from cc_daemon.config import load_settings

    return load_settings(args.config, flag_overrides(args))


def _configure_daemon_logging(settings: Any) -> None:
    from cc_daemon.ground.logsetup import configure_logging, flush_rate_limited, resolve_format

    flush_rate_limited(everything=True)  # a reconfiguration must not lose held-back counts
    # "auto" follows stdout: a terminal gets the console renderer, journald
    # (or a pipe, or a file) gets JSON lines. The log itself goes to stderr.
    configure_logging(resolve_format(settings.log.format, sys.stdout), settings.log.level)


def _run_daemon(args: argparse.Namespace, held: SignalHold) -> int:
    from cc_daemon.ground.leanimports import (
        import_daemon_libraries_lean,
        pydantic_without_plugins,
    )

    import_daemon_libraries_lean()  # before anything imports asyncio or structlog
    import asyncio

    with pydantic_without_plugins():  # the configuration's models are built here
        from cc_daemon.daemon.preflight import check_paths, open_journal
        from cc_daemon.daemon.service import Daemon
        from cc_daemon.daemon.signals import stopped_before_ready
        from cc_daemon.daemon.simgate import check_backend_allowed
        from cc_daemon.daemon.simulators import Simulators
        from cc_daemon.drivers.winch.factory import check_pin_library

    simulators = Simulators(sonde=_simulated_sonde, drum=_simulated_drum)

    # `held` has caught the daemon's signals since the first instruction
    # (cc_daemon.__main__): a SIGHUP now waits for the loop, a stop ends us cleanly.
    settings = _load(args)
    check_paths(settings)  # a port or journal path that can never work: exit 2 now
    check_backend_allowed(settings)  # a simulated winch not asked for: exit 2, nothing opened
    check_pin_library(settings)  # no lgpio for a GPIO winch: exit 1 before the journal exists
    _configure_daemon_logging(settings)
    if held.stop_requested():  # nothing opened yet, the probe never moved
        return stopped_before_ready(held)
    daemon = Daemon(settings, journal=open_journal(settings), simulators=simulators)

    def reload() -> None:  # a SIGHUP: the reload's module is imported at the first
        from cc_daemon.daemon.reload import Reloader

        Reloader(daemon, lambda: _load(args), _configure_daemon_logging)()

    return asyncio.run(_serve(daemon, held, reload))


# The simulated devices, imported from the simulator only when a backend set to one
# (sonde.backend = "sim", winch.gpio.pin_factory = "mock") is built, at start or on
# a reload: a daemon with real devices loads nothing of `cc_daemon.sim`.
def _simulated_sonde(path: Path, line_out: Callable[[], float], settings: Any) -> Any:
    from cc_daemon.sim.devices import SIMULATORS

    assert SIMULATORS.sonde is not None
    return SIMULATORS.sonde(path, line_out, settings)


def _simulated_drum(settings: Any) -> Any:
    from cc_daemon.sim.devices import SIMULATORS

    assert SIMULATORS.drum is not None
    return SIMULATORS.drum(settings)


async def _serve(daemon: Any, held: SignalHold, reload: Callable[[], None] | None = None) -> int:
    from cc_daemon.daemon.signals import DaemonSignals

    # Every signal of the table (docs/signals.md), the ones held until now first.
    with DaemonSignals(daemon, reload).delivered(held):
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


def main(argv: Sequence[str] | None = None, *, held: SignalHold | None = None) -> int:
    """The `cc-daemon` command; its output watched (`output.guarded`)."""
    return guarded(lambda: _main(argv, held=held))


def _main(argv: Sequence[str] | None = None, *, held: SignalHold | None = None) -> int:
    """`held`: the signals `cc_daemon.__main__` caught from the first instruction (caught
    here when called directly). The daemon keeps them; every other command gets its
    own handlers back, and what was held is raised again."""
    owned = held is None  # called in-process (a test): leave the handlers as found
    held = held if held is not None else SignalHold.hold()
    daemon_mode = False
    try:
        words = sys.argv[1:] if argv is None else argv
        parser, args = parse_command_line(words)
        handler = getattr(args, "handler", None)
        daemon_mode = handler is None and not args.simulate
        if not daemon_mode:
            held.release()
        stray = [] if args.simulate else _simulate_only_options(parser, args, words)
        if stray:
            print(f"cc-daemon: {', '.join(stray)} applies only with --simulate", file=sys.stderr)
            return EXIT_USAGE
        if handler is not None:
            code: int = handler(args)
            return code
        if args.simulate:
            from cc_daemon.sim.commands import run_from_args

            return run_from_args(args, _load(args))
        return _run_daemon(args, held)
    except ConfigError as exc:
        print(str(exc), file=sys.stderr)
        return EXIT_USAGE
    except WinchFault as exc:  # the winch's pins cannot be opened: nothing to drive
        print(f"cc-daemon: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    finally:
        if not daemon_mode:  # --help, a usage error: the handlers go back all the same
            with contextlib.suppress(KeyboardInterrupt):  # a Ctrl-C held meanwhile
                held.release()
        elif owned:
            held.restore()
