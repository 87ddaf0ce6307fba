"""Ask the daemon's status socket for one document (blocking, bounded, time-limited).

Used by `cc-daemon status`, `cc-daemon doctor` and the field page; it never
writes to the socket, never waits longer than its timeout, and believes only
the daemon (`cli.daemon_socket`: not a socket another user could have bound,
not a peer other than the daemon's user). A document is at most 1 MiB and
nested at most `MAX_DEPTH` deep (the daemon's is 3): anything else is refused
with one line, never a traceback. A connection closed unanswered (the daemon's
cap on clients at once) is asked again until the timeout.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from cc_daemon.cli.daemon_socket import (
    GROUP_HINT,
    NoSocket,
    NotAuthorised,
    SocketTrouble,
    exchange,
)
from cc_daemon.core.errors import CcDaemonError

MAX_DOCUMENT = 1 << 20
MAX_DEPTH = 32
_RETRY_S = 0.05


class StatusUnavailable(CcDaemonError):
    """The daemon's status could not be read; the message says why and what to try."""


def read_status(path: Path, timeout_s: float = 3.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            raw = exchange(path, b"", max(deadline - time.monotonic(), 0.001), MAX_DOCUMENT)
        except NoSocket:
            raise StatusUnavailable(
                f"no status socket at {path}: is the daemon running "
                "(systemctl status cc-daemon), and is status.path the same for both?"
            ) from None
        except NotAuthorised:
            raise StatusUnavailable(
                f"{path}: not authorised (permission denied): add yourself to the daemon's"
                f" group ({GROUP_HINT})"
            ) from None
        except SocketTrouble as exc:
            raise StatusUnavailable(str(exc)) from None
        if raw or time.monotonic() + _RETRY_S >= deadline:
            break
        time.sleep(_RETRY_S)  # closed unanswered: too many clients at once
    if not raw:
        raise StatusUnavailable(f"{path}: closed unanswered (too many clients at once?)")
    return _document(path, raw)


def _document(path: Path, raw: bytes) -> dict[str, Any]:
    try:
        document = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        raise StatusUnavailable(f"{path}: the answer is not a status document") from None
    except RecursionError:
        document = None  # nested past the interpreter's own limit
    if not isinstance(document, dict) or _depth(document) > MAX_DEPTH:
        raise StatusUnavailable(f"{path}: the answer is not a status document")
    return document


def _depth(value: Any) -> int:
    """How deep `value` nests lists and objects (iteratively: no recursion to run out of)."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            item = list(item.values())
        if isinstance(item, list):
            deepest = max(deepest, depth)
            stack.extend((child, depth + 1) for child in item)
    return deepest
