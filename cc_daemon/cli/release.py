"""`cc-daemon release --reason TEXT`: release a stranded station by hand.

For a broken witness of home only: the operator has seen the probe on board,
but the winch can never verify it, so the daemon holds the station with R-L.
This asks the running daemon's control socket (beside its status socket) to
send R-F; the daemon journals who asked and why. Exit status 0 released, 1 the
daemon refused (no stranded station, not authorised), 2 no daemon to ask.
"""

from __future__ import annotations

import argparse
import json
import socket
from pathlib import Path

TIMEOUT_S = 5.0


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "release",
        help="release a stranded station by hand (R-F): only with the probe seen on board",
        description="Tell the running daemon that the probe is on board although the winch "
        "cannot verify it (a broken switch or encoder): it sends R-F and the boat moves on. "
        "Root or the service's group only. Exit status 0 released, 1 refused, 2 no daemon.",
    )
    p.add_argument("--reason", required=True, help="what the operator saw (journaled)")
    p.add_argument("--config", type=Path, help="TOML configuration file")
    p.add_argument("--socket", type=Path, help="the control socket (default: beside status)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from cc_daemon.config.statuspaths import client_socket_path
    from cc_daemon.daemon.control_server import control_path

    path = args.socket
    if path is None:
        status, journal = None, None
        if args.config is not None:
            from cc_daemon.config import load_settings

            settings = load_settings(args.config, {})
            status, journal = settings.status, settings.store.path
        path = control_path(client_socket_path(status, journal=journal))
    try:
        answer = ask_daemon(path, f"release {' '.join(args.reason.split())}")
    except OSError as exc:
        print(f"cc-daemon release: cannot reach the daemon at {path}: {exc}")
        return 2
    print(f"cc-daemon release: {answer['message']}")
    return 0 if answer["ok"] else 1


def ask_daemon(path: Path, line: str) -> dict[str, object]:
    """One request on the control socket, its JSON answer. Raises OSError."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(TIMEOUT_S)
        sock.connect(str(path))
        sock.sendall(line.encode() + b"\n")
        reply = sock.makefile("rb").readline()
    answer = json.loads(reply) if reply else {"ok": False, "message": "no answer"}
    return dict(answer)
