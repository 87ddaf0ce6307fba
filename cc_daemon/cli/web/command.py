"""`cc-daemon web`: run the field page, or `--hash-password` for its setting."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import getpass
import signal
import sys
from pathlib import Path

EXIT_USAGE = 2


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "web",
        help="the field page: status and the day's data in a browser (read-only)",
        description="Serve the field page (docs/web.md): the daemon's status and the "
        "journal's surveys, read-only, to any browser on the boat's network.",
    )
    p.add_argument("--config", type=Path, help="TOML configuration file")
    p.add_argument(
        "--listen", help='host:port to listen on [web.listen] ("127.0.0.1:8080"); port 0: any free'
    )
    p.add_argument("--db", type=Path, help="the journal to read [store.path]")
    p.add_argument("--socket", type=Path, help="the daemon's status socket [status.path]")
    p.add_argument(
        "--hash-password",
        action="store_true",
        help="read a password on stdin and print its [web] password_hash setting",
    )
    p.set_defaults(handler=run_web)


def run_web(args: argparse.Namespace) -> int:
    if args.hash_password:
        return _hash_password()
    from cc_daemon.cli.data import journal_path
    from cc_daemon.cli.status.command import socket_candidates
    from cc_daemon.cli.web import weblog
    from cc_daemon.cli.web.server import Sources, serve
    from cc_daemon.config import WebSettings, load_settings
    from cc_daemon.ground.logsetup import flush_rate_limited

    settings = load_settings(args.config)  # a bad key: ConfigError, exit 2, nothing bound
    web = settings.web
    if args.listen is not None:
        # Port 0 on the command line only: a free port, said on stderr (for tests).
        listen = args.listen.removesuffix(":0") + ":1" if args.listen.endswith(":0") else None
        try:
            WebSettings(listen=listen or args.listen)
        except ValueError:
            print(f'cc-daemon web: --listen {args.listen}: must be "host:port"', file=sys.stderr)
            return EXIT_USAGE
        web = web.model_copy(update={"listen": args.listen})
    # The daemon writing the journal read here: found by it, as `status --db` does.
    sockets = socket_candidates(args.socket, args.config, args.db)
    sources = Sources(
        socket=sockets[0],
        also=tuple(sockets[1:]),
        journal=journal_path(argparse.Namespace(db=args.db or settings.store.path)),
        password_hash=web.password_hash,
        hosts=frozenset(web.hosts),
        survey=settings.survey,
    )

    def ready(address: str, connections: int) -> None:
        from cc_daemon.cli.doctor.software import check_web

        guard = "with a password" if web.password_hash else "no password"
        print(
            f"cc-daemon web: http://{address}/ ({guard}; status from {sources.socket}; "
            f"at most {connections} connections)",
            file=sys.stderr,
        )
        for check in check_web(settings.model_copy(update={"web": web})):
            if check.level != "OK":
                print(f"cc-daemon web: WARNING: {check.detail}; {check.fix}", file=sys.stderr)
        sys.stderr.flush()

    weblog.configure(settings.log.format, settings.log.level)

    async def run() -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(weblog.loop_error)
        # systemd's stop: the downloads under way end (their temporary files
        # removed), the connections close, and the process exits 0.
        stop = asyncio.Event()
        loop.add_signal_handler(signal.SIGTERM, stop.set)
        flusher = asyncio.create_task(weblog.flush_forever(), name="web-log")
        stopped = asyncio.create_task(stop.wait(), name="web-stop")
        serving = asyncio.create_task(serve(sources, web.listen, ready=ready), name="web")
        try:
            await asyncio.wait([serving, stopped], return_when=asyncio.FIRST_COMPLETED)
            serving.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await serving  # raises its OSError if it could not bind
        finally:
            flusher.cancel()
            stopped.cancel()
            flush_rate_limited(everything=True)

    try:
        asyncio.run(run())
    except OSError as exc:
        print(f"cc-daemon web: web.listen = {web.listen}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    return 0


def _hash_password() -> int:
    from cc_daemon.cli.web.auth import hash_password

    if sys.stdin.isatty():
        password = getpass.getpass("password for the field page: ")
    else:
        password = sys.stdin.readline().rstrip("\r\n")
    if not password:
        print("cc-daemon web: an empty password protects nothing", file=sys.stderr)
        return EXIT_USAGE
    print(f'password_hash = "{hash_password(password)}"')
    print("cc-daemon web: put that line under [web] in the configuration", file=sys.stderr)
    return 0
