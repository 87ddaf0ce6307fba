"""Where the status socket is: one rule for the daemon that binds it and the tools
that ask it. It reads the environment and the settings; it never touches a file.

The rule, in order:
1. `status.path`, when configured: the daemon binds it, `status` asks it.
2. Under systemd (`$RUNTIME_DIRECTORY`, the unit's RuntimeDirectory=cc-daemon):
   `$RUNTIME_DIRECTORY/status.sock`, i.e. `/run/cc-daemon/status.sock`.
3. Started by hand, with a journal configured (`store.path` or `--db`): beside
   the journal, `<journal>.status.sock` (one socket per journal: two daemons on
   two journals never fight over one path).
4. Started by hand without one: the user's runtime directory,
   `$XDG_RUNTIME_DIR/cc-daemon/status.sock`; with no runtime directory, beside
   the default journal (`./cc-daemon.db.status.sock`).

A path too long for a Unix socket (107 bytes) is passed over for the next. A
tool cannot know whether the daemon is a service, so it asks the first of
`client_socket_paths` that exists: the by-hand path from the same
configuration, then the service's.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from cc_daemon.config import StatusSettings

SOCKET_NAME = "status.sock"
# What the installed unit's RuntimeDirectory=cc-daemon gives the daemon.
SERVICE_SOCKET = Path("/run/cc-daemon") / SOCKET_NAME
DEFAULT_JOURNAL = Path("cc-daemon.db")  # the journal's own default outside systemd
_SUN_PATH_MAX = 107  # sockaddr_un.sun_path is 108 bytes, NUL included


def _fits(path: Path) -> bool:
    return len(os.fsencode(path)) <= _SUN_PATH_MAX


def _env(env: Mapping[str, str] | None) -> Mapping[str, str]:
    return os.environ if env is None else env


def hand_socket_path(journal: Path | None, env: Mapping[str, str] | None = None) -> Path | None:
    """Where a daemon started by hand binds (rules 3 and 4); None if nothing fits."""
    candidates: list[Path] = []
    if journal is not None:
        candidates.append(Path(f"{Path(journal).absolute()}.{SOCKET_NAME}"))
    runtime = _env(env).get("XDG_RUNTIME_DIR", "")
    if runtime:
        candidates.append(Path(runtime) / "cc-daemon" / SOCKET_NAME)
    candidates.append(Path(f"{DEFAULT_JOURNAL.absolute()}.{SOCKET_NAME}"))
    return next((c for c in candidates if _fits(c)), None)


def daemon_socket_path(
    settings: StatusSettings, env: Mapping[str, str] | None = None, journal: Path | None = None
) -> Path | None:
    """The path the daemon binds: `status.path`, else `$RUNTIME_DIRECTORY`, else by hand."""
    if settings.path is not None:
        return settings.path
    # systemd joins several RuntimeDirectory= entries with ':'; the first is ours.
    runtime = _env(env).get("RUNTIME_DIRECTORY", "").split(":")[0]
    if runtime:
        return Path(runtime) / SOCKET_NAME
    return hand_socket_path(journal, env)


def client_socket_paths(
    settings: StatusSettings | None,
    env: Mapping[str, str] | None = None,
    journal: Path | None = None,
) -> list[Path]:
    """The paths a tool may ask, in order: the configured one alone, else by hand, service."""
    if settings is not None and settings.path is not None:
        return [settings.path]
    hand = hand_socket_path(journal, env)
    return [hand, SERVICE_SOCKET] if hand is not None else [SERVICE_SOCKET]


def client_socket_path(
    settings: StatusSettings | None,
    env: Mapping[str, str] | None = None,
    journal: Path | None = None,
) -> Path:
    """The first of `client_socket_paths` that exists, else the service's."""
    paths = client_socket_paths(settings, env, journal)
    return next((p for p in paths if p.exists()), paths[-1])
