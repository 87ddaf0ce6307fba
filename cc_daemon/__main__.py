"""`python -m cc_daemon` and the `cc-daemon` script: hold the signals, then the command line.

The signals come first, before anything heavy is imported (argparse, asyncio,
pydantic, structlog): a SIGHUP or SIGTERM in the daemon's first second must not
end it (`cc_daemon.ground.signals`). Only the standard library's `signal` and
that small module are loaded before the handlers are in place.
"""

from cc_daemon.ground.signals import SignalHold


def main() -> int:
    held = SignalHold.hold()
    try:
        from cc_daemon.cli.app import main as command_line

        return command_line(held=held)
    finally:
        # Still held (the daemon's run): ignored to the last instant of the process.
        held.ignore_from_now()


if __name__ == "__main__":
    raise SystemExit(main())
