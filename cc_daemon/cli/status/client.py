"""Ask the daemon's status socket for one document (blocking, bounded, time-limited).

Used by `cc-daemon status` and `cc-daemon doctor`; it never writes to the socket
and never waits longer than its timeout.
"""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path
from typing import Any

from cc_daemon.core.errors import CcDaemonError

MAX_DOCUMENT = 1 << 20


class StatusUnavailable(CcDaemonError):
    """The daemon's status could not be read; the message says why and what to try."""


def read_status(path: Path, timeout_s: float = 3.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    chunks: list[bytes] = []
    size = 0
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
            conn.settimeout(timeout_s)
            conn.connect(str(path))
            while True:
                conn.settimeout(max(deadline - time.monotonic(), 0.001))
                chunk = conn.recv(65536)
                if not chunk:
                    break
                size += len(chunk)
                if size > MAX_DOCUMENT:
                    raise StatusUnavailable(f"{path}: the answer is larger than 1 MiB")
                chunks.append(chunk)
    except FileNotFoundError:
        raise StatusUnavailable(
            f"no status socket at {path}: is the daemon running "
            "(systemctl status cc-daemon), and is status.path the same for both?"
        ) from None
    except PermissionError:
        raise StatusUnavailable(
            f"{path}: permission denied: add yourself to the daemon's group "
            "(sudo usermod -aG cc-daemon $USER, then log in again)"
        ) from None
    except ConnectionRefusedError:
        raise StatusUnavailable(f"{path}: nobody answers (the daemon is not running)") from None
    except TimeoutError:
        raise StatusUnavailable(f"{path}: no answer within {timeout_s:g} s") from None
    except OSError as exc:
        raise StatusUnavailable(f"{path}: {exc.strerror or exc}") from None
    try:
        document = json.loads(b"".join(chunks))
    except (ValueError, UnicodeDecodeError):
        raise StatusUnavailable(f"{path}: the answer is not a status document") from None
    if not isinstance(document, dict):
        raise StatusUnavailable(f"{path}: the answer is not a status document")
    return document
