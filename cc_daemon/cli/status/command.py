"""`cc-daemon status`: the running daemon's status for a person (`--json` for scripts,
`--watch` live). Exit status 1 when the daemon cannot be asked."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cc_daemon.cli.status.client import StatusUnavailable, read_status
from cc_daemon.cli.status.view import render_text, watch
from cc_daemon.config import StatusSettings
from cc_daemon.config.statuspaths import (
    SIMULATOR_JOURNAL,
    client_socket_paths,
    hand_socket_path,
    present,
)
from cc_daemon.core.errors import ConfigError


def add_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "status",
        help="ask the running daemon what it is doing",
        description="Read the running daemon's status socket (it needs no privilege beyond "
        "membership of the daemon's group). Exit status 1 if the daemon cannot be asked.",
    )
    p.add_argument("--socket", type=Path, help="the status socket (default: from the config)")
    p.add_argument(
        "--config", dest="status_config", type=Path, help="read status.path from this file"
    )
    p.add_argument(
        "--db",
        dest="status_db",
        type=Path,
        help="the journal of a daemon started by hand with --db: its socket is found by it",
    )
    p.add_argument("--json", action="store_true", help="the document as one JSON line")
    p.add_argument("--watch", action="store_true", help="a live view, until Ctrl-C")
    p.add_argument("--interval", type=float, default=1.0, help="--watch refresh, seconds (1)")
    p.add_argument("--updates", type=int, help="--watch: stop after this many refreshes")
    p.set_defaults(handler=run_status)


def socket_candidates(
    socket_path: Path | None, config: Path | None, db: Path | None = None
) -> list[Path]:
    """--socket alone, else the configuration's status.path alone, else where a daemon
    started by hand with the same configuration (and --db) binds, then, with no
    journal named anywhere, where `cc-daemon --simulate` run here binds (its
    `./simulate.db`), then the service's."""
    if socket_path is not None:
        return [socket_path]
    from cc_daemon.config import load_settings

    journal: Path | None = None
    try:
        loaded = load_settings(config)
        settings: StatusSettings | None = loaded.status
        journal = loaded.store.path
    except ConfigError:
        if config is not None:
            raise
        settings = None  # e.g. /etc/cc-daemon unreadable to this user: use the default
    # The same rule the daemon bound by (`statuspaths`).
    paths = client_socket_paths(settings, journal=db if db is not None else journal)
    if db is None and journal is None and len(paths) > 1:
        simulation = hand_socket_path(SIMULATOR_JOURNAL.absolute())
        if simulation is not None and simulation not in paths:
            paths.insert(-1, simulation)
    return paths


def run_status(args: argparse.Namespace) -> int:
    tried = socket_candidates(args.socket, args.status_config, args.status_db)
    path = next((p for p in tried if present(p)), tried[-1])
    if args.watch:
        return watch(
            lambda: read_status(path), interval_s=max(args.interval, 0.1), updates=args.updates
        )
    try:
        document = read_status(path)
    except StatusUnavailable as exc:
        others = [str(p) for p in tried if p != path]
        also = f" (nor at {', '.join(others)})" if others else ""
        print(f"cc-daemon status: {exc}{also}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(document, sort_keys=True))
    else:
        print(render_text(document))
    return 0
