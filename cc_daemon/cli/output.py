"""Every command's standard output, when it cannot be written: one line, a non-zero exit.

This module owns the one place where a command's failure to write its output
(standard output on a full disk or `/dev/full`, an I/O error on a dead
terminal) becomes `cc-daemon: cannot write the output: <reason>` on standard
error and exit status 74 (EX_IOERR), instead of a traceback, or a silent exit
0 with the output lost. A reader that leaves a pipe (`| head`) is not an
error: exit 0, as before.

It wraps standard output for the duration of a command, so a failure is
attributed to the output only when the output itself raised; any other
`OSError` (a journal, a serial port) goes on to the command's own handling.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable
from typing import Any, TextIO

__all__ = ["EXIT_OUTPUT", "guarded"]

EXIT_OUTPUT = 74  # sysexits.h EX_IOERR: an error while doing I/O on a file


class _Watched:
    """Standard output, remembering whether writing to it failed."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        self.failure: OSError | None = None

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError as exc:
            self.failure = exc
            raise

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError as exc:
            self.failure = exc
            raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _silence_stdout() -> None:
    # Whatever is still buffered cannot be written: point the descriptor at
    # /dev/null so the interpreter's last flush at exit has nowhere to fail.
    stdout = sys.__stdout__
    if stdout is None:
        return
    with contextlib.suppress(OSError, ValueError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), stdout.fileno())


def guarded(run: Callable[[], int]) -> int:
    """Run a command with its output watched; its exit status, or 74 if the output failed."""
    original = sys.stdout
    watched = _Watched(original)
    sys.stdout = watched
    try:
        try:
            try:
                code = run()
            except SystemExit:
                # argparse's --version and --help exit through here, and it
                # swallows a failed write: the record of it is `failure`.
                sys.stdout.flush()
                if watched.failure is not None:
                    raise watched.failure from None
                raise
            sys.stdout.flush()
            if watched.failure is not None:  # a write failed and someone swallowed it
                raise watched.failure
        except OSError as exc:
            if watched.failure is None:
                raise
            if isinstance(exc, BrokenPipeError):
                _silence_stdout()
                return 0  # the reader left: not an error
            reason = exc.strerror or str(exc)
            with contextlib.suppress(OSError):
                print(f"cc-daemon: cannot write the output: {reason}", file=sys.stderr)
            _silence_stdout()
            return EXIT_OUTPUT
        return code
    finally:
        sys.stdout = original
