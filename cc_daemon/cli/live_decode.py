"""`cc-daemon decode --port PATH`: decode a live serial line until Ctrl-C.

For an engineer on a sniffer cable or a spare UART: the same `SerialLink` the
daemon uses (so an unplugged adapter is reopened the same way), a parser that
listens to both directions, and one printed line per frame or error. The port
is opened non-exclusively so it can sit beside another reader, but only when
asked (`shared`): a UART gives each byte to one reader only, so reading the
daemon's own port would steal the autopilot's frames from it. Sniffing needs a
second UART wired to the line (two to see both directions).
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sys

from cc_daemon.cli.decode import format_event, summary_line
from cc_daemon.core.protocol import Parser, Sender
from cc_daemon.drivers.link import SerialLink
from cc_daemon.ground.portusers import port_users

EXIT_USAGE = 2


async def _decode(port: str, baudrate: int, *, as_json: bool, accept_g_alias: bool) -> int:
    parser = Parser(Sender.BOTH, accept_g_alias=accept_g_alias)

    def on_data(data: bytes) -> None:
        for event in parser.events(data):
            print(format_event(event, as_json=as_json), flush=True)

    def on_state(up: bool, reason: str) -> None:
        state = "open" if up else f"lost ({reason}); reopening"
        print(f"# {port}: {state}", file=sys.stderr, flush=True)

    link = SerialLink(port, on_data=on_data, on_state=on_state, baudrate=baudrate, exclusive=False)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    task = asyncio.create_task(link.run(), name="serial-link")
    try:
        await stop.wait()
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    stats = parser.stats
    print(summary_line(stats), file=sys.stderr)
    return 1 if stats.errors else 0


def decode_port(
    port: str, baudrate: int, *, as_json: bool, accept_g_alias: bool, shared: bool = False
) -> int:
    if not shared:
        users = port_users(port)
        if users:
            named = ", ".join(str(user) for user in users)
            print(
                f"cc-daemon decode: {port} is open in another process: {named}. Reading it "
                "too would take bytes from it (each byte goes to one reader only). To "
                "sniff a line, wire a second UART to it (two to see both directions); "
                "--shared reads anyway.",
                file=sys.stderr,
            )
            return EXIT_USAGE
    return asyncio.run(_decode(port, baudrate, as_json=as_json, accept_g_alias=accept_g_alias))
