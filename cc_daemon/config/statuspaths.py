"""Where the status socket is: one rule for the daemon that binds it and the tools
that ask it. It reads the environment and the settings, and looks at directories'
owners and modes; it never creates, opens or changes a file (the daemon makes
the private directory, `daemon.socket_listener`).

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

Beside a journal whose directory someone else could write (`shared_directory`:
a world-writable one such as /tmp, or one of another user's), a socket could be
bound first, or replaced, by anyone: there the by-hand rules use the user's
private directory instead (`private_directory`: `$XDG_RUNTIME_DIR/cc-daemon`,
else `$TMPDIR/cc-daemon-<uid>`, made 0700), the socket named after the journal
(`<name>-<hash of its path>.status.sock`, `private_socket`).

A path too long for a Unix socket (107 bytes) is passed over for the next. A
tool cannot know whether the daemon is a service, so it asks the first of
`client_socket_paths` that exists: the by-hand path from the same
configuration, then the service's.
"""

from __future__ import annotations

import hashlib
import os
import stat
from collections.abc import Collection, Mapping
from pathlib import Path

from cc_daemon.config import StatusSettings

SOCKET_NAME = "status.sock"
# What the installed unit's RuntimeDirectory=cc-daemon gives the daemon.
SERVICE_SOCKET = Path("/run/cc-daemon") / SOCKET_NAME
SERVICE_USER = "cc-daemon"  # the installed unit's User= (systemd/cc-daemon.sysusers)
DEFAULT_JOURNAL = Path("cc-daemon.db")  # the journal's own default outside systemd
SIMULATOR_JOURNAL = Path("simulate.db")  # `cc-daemon --simulate`'s default --db
_SUN_PATH_MAX = 107  # sockaddr_un.sun_path is 108 bytes, NUL included
_NAME_MAX = 40  # of a journal's name, in a private socket's name


def _fits(path: Path) -> bool:
    return len(os.fsencode(path)) <= _SUN_PATH_MAX


def _env(env: Mapping[str, str] | None) -> Mapping[str, str]:
    return os.environ if env is None else env


def shared_directory(path: Path, trusted: Collection[int] | None = None) -> str | None:
    """Why a socket at `path` could be bound first, or replaced, by a user not in
    `trusted` (default: root and ourselves), or None if it cannot.

    Its directory (symbolic links followed) must belong to a trusted user and be
    writable by no one else: not world-writable, the sticky /tmp included (anyone
    may create a name there). Each directory above it must belong to a trusted
    user too, and be world-writable only if sticky (then nobody else can rename
    what is inside). A directory that cannot be looked at, or is not there yet,
    is no reason: binding or connecting says what is wrong with it.
    """
    uids = {0, os.geteuid()} if trusted is None else set(trusted)
    directory = Path(os.path.realpath(os.path.abspath(path.parent)))
    first = True
    for each in (directory, *directory.parents):
        try:
            info = os.stat(each)
        except OSError:
            return None
        mode = info.st_mode
        if mode & stat.S_IWOTH and (first or not mode & stat.S_ISVTX):
            return f"{each} may be written by every user"
        if info.st_uid not in uids:
            return f"{each} belongs to another user (uid {info.st_uid})"
        first = False
    return None


def private_directory(env: Mapping[str, str] | None = None) -> Path:
    """The user's own directory for sockets: `$XDG_RUNTIME_DIR/cc-daemon`, else
    `$TMPDIR/cc-daemon-<uid>` (/tmp by default). The daemon makes it 0700 and
    refuses one that is not its own (`daemon.socket_listener`)."""
    environ = _env(env)
    runtime = environ.get("XDG_RUNTIME_DIR", "")
    if runtime:
        return Path(runtime) / "cc-daemon"
    return Path(environ.get("TMPDIR") or "/tmp") / f"cc-daemon-{os.geteuid()}"


def private_socket(journal: Path, env: Mapping[str, str] | None = None) -> Path:
    """The socket of a daemon whose journal's directory is shared: in the private
    directory, named after the journal (its name, cut, and a hash of its path)."""
    absolute = Path(journal).absolute()
    digest = hashlib.sha256(os.fsencode(absolute)).hexdigest()[:12]
    return private_directory(env) / f"{absolute.name[:_NAME_MAX]}-{digest}.{SOCKET_NAME}"


def _beside(journal: Path, env: Mapping[str, str] | None) -> Path:
    path = Path(f"{Path(journal).absolute()}.{SOCKET_NAME}")
    return private_socket(journal, env) if shared_directory(path) is not None else path


def hand_socket_path(journal: Path | None, env: Mapping[str, str] | None = None) -> Path | None:
    """Where a daemon started by hand binds (rules 3 and 4); None if nothing fits."""
    return next((c for c in _hand_candidates(journal, env) if _fits(c)), None)


def _hand_candidates(journal: Path | None, env: Mapping[str, str] | None) -> list[Path]:
    candidates: list[Path] = []
    if journal is not None:
        candidates.append(_beside(journal, env))
    runtime = _env(env).get("XDG_RUNTIME_DIR", "")
    if runtime:
        candidates.append(Path(runtime) / "cc-daemon" / SOCKET_NAME)
    candidates.append(_beside(DEFAULT_JOURNAL, env))
    return candidates


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


def present(path: Path) -> bool:
    """Whether something is at `path`, or may be: a directory we may not search (the
    service's, 0750, to a user outside its group) hides it, and asking is what
    says "not authorised". Never raises."""
    try:
        path.lstat()
    except PermissionError:
        return True
    except OSError:
        return False
    return True


def client_socket_path(
    settings: StatusSettings | None,
    env: Mapping[str, str] | None = None,
    journal: Path | None = None,
) -> Path:
    """The first of `client_socket_paths` that is there, else the service's."""
    paths = client_socket_paths(settings, env, journal)
    return next((p for p in paths if present(p)), paths[-1])
