"""The `cc-daemon` command line: the daemon itself and its tools.

    cc-daemon [--config PATH] [--port ...]   run the daemon (the systemd service)
    cc-daemon --simulate [...]               a whole survey against a simulated autopilot
    cc-daemon decode ...                     read frames: hex, a capture on stdin, a live port
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from cc_daemon import __version__
from cc_daemon.decode import HexInputError, decode_chunks, parse_hex, print_events, read_stdin_chunks


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
    p.add_argument("--baudrate", type=int, default=9600, help="baud rate for --port (9600)")


def _run_decode(args: argparse.Namespace) -> int:
    try:
        if args.port:
            from cc_daemon.live_decode import decode_port

            return decode_port(
                args.port, args.baudrate, as_json=args.json, accept_g_alias=args.accept_g_alias
            )
        if args.hex:
            chunks: list[bytes] | object = [parse_hex(" ".join(args.hex))]
        else:
            chunks = read_stdin_chunks(sys.stdin.buffer, hex_text=args.hex_stdin)
        events = decode_chunks(chunks, accept_g_alias=args.accept_g_alias)  # type: ignore[arg-type]
        return print_events(events, as_json=args.json)
    except HexInputError as exc:
        print(f"cc-daemon decode: {exc}", file=sys.stderr)
        return 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cc-daemon", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"cc-daemon {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_decode(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "decode":
        return _run_decode(args)
    parser.print_help()
    return 0
