"""`cc-daemon release --reason TEXT`: release a stranded station by hand.

For a broken witness of home only: the operator has seen the probe on board,
but the winch can never verify it, so the daemon holds the station with R-L.
This asks the running daemon's control socket (beside its status socket) to
send R-F; the daemon journals who asked and why. Exit status 0 released, 1 the
daemon refused (no stranded station, not authorised) or the socket is not the
daemon's, 2 no daemon to ask. Whatever happens is one line, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from cc_daemon.cli.daemon_socket import (
    NoDaemon,
    NotTheDaemon,
    SocketTrouble,
    Unreachable,
    exchange,
)

TIMEOUT_S = 5.0
MAX_ANSWER = 64 * 1024
EXIT_REFUSED = 1
EXIT_NO_DAEMON = 2
EXIT_USAGE = 2


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
    p.add_argument("--db", type=Path, help="the journal of a daemon started by hand with --db")
    p.add_argument("--socket", type=Path, help="the control socket (default: beside status)")
    p.set_defaults(handler=run)


def control_socket(settings: Any, journal: Path | None) -> Path:
    """The control socket beside the status socket the same rule finds."""
    from cc_daemon.config.statuspaths import client_socket_path
    from cc_daemon.daemon.control_server import control_path

    status = settings.status if settings is not None else None
    if journal is None and settings is not None:
        journal = settings.store.path
    return control_path(client_socket_path(status, journal=journal))


def run(args: argparse.Namespace) -> int:
    from cc_daemon.daemon.control_request import MAX_REQUEST

    line = f"release {' '.join(args.reason.split())}".encode()
    if len(line) > MAX_REQUEST:
        print(
            f"cc-daemon release: --reason is too long ({len(line) - 8} bytes; at most"
            f" {MAX_REQUEST - 8})",
            file=sys.stderr,
        )
        return EXIT_USAGE
    path = args.socket
    if path is None:
        settings = None
        if args.config is not None:
            from cc_daemon.config import load_settings

            settings = load_settings(args.config, {})
        path = control_socket(settings, args.db)
    try:
        ok, message = ask_daemon(path, line)
    except NoDaemon as exc:
        print(f"cc-daemon release: cannot reach the daemon: {exc}", file=sys.stderr)
        return EXIT_NO_DAEMON
    except SocketTrouble as exc:
        print(f"cc-daemon release: {exc}; nothing was released", file=sys.stderr)
        return EXIT_REFUSED
    print(f"cc-daemon release: {message}")
    return 0 if ok else EXIT_REFUSED


def ask_daemon(path: Path, line: bytes) -> tuple[bool, str]:
    """One request on the control socket and the daemon's answer (done, message).
    Raises `SocketTrouble`: `NoDaemon` only when no daemon listens there."""
    raw = exchange(path, line + b"\n", TIMEOUT_S, MAX_ANSWER)
    if not raw:
        raise Unreachable(f"{path}: the daemon closed the connection unanswered")
    try:
        answer = json.loads(raw.splitlines()[0])
        ok, message = answer["ok"], answer["message"]
    except (ValueError, IndexError, KeyError, TypeError, RecursionError):
        raise NotTheDaemon(f"{path}: the answer is not the daemon's") from None
    if not isinstance(ok, bool) or not isinstance(message, str):
        raise NotTheDaemon(f"{path}: the answer is not the daemon's")
    return ok, message
