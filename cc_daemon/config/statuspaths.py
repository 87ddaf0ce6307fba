"""Where the status socket is: one rule for the daemon that binds it and the tools
that ask it. It reads the environment and the settings; it never touches a file."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from cc_daemon.config import StatusSettings

SOCKET_NAME = "status.sock"
# What the installed unit's RuntimeDirectory=cc-daemon gives the daemon.
SERVICE_SOCKET = Path("/run/cc-daemon") / SOCKET_NAME


def daemon_socket_path(
    settings: StatusSettings, env: Mapping[str, str] | None = None
) -> Path | None:
    """The path the daemon binds: `status.path`, else in `$RUNTIME_DIRECTORY`.

    None outside systemd with no path configured: a daemon run by hand (or a test,
    or `--simulate`) must not litter its working directory or fight another one
    over a shared default.
    """
    if settings.path is not None:
        return settings.path
    # systemd joins several RuntimeDirectory= entries with ':'; the first is ours.
    runtime = (os.environ if env is None else env).get("RUNTIME_DIRECTORY", "").split(":")[0]
    return Path(runtime) / SOCKET_NAME if runtime else None


def client_socket_path(settings: StatusSettings | None) -> Path:
    """The path a tool asks: the configured one, else the service's."""
    if settings is not None and settings.path is not None:
        return settings.path
    return SERVICE_SOCKET
