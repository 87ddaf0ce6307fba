"""Start-up checks of the paths a configuration names: refuse what can never work.

The configuration's schema (`cc_daemon.config`) cannot look at the filesystem; this
module does, once, before the daemon opens its serial port: a `serial.port`
that exists and is not a terminal, or a `store.path` that is a directory, a
device, under /proc, /sys or /dev, or in a directory that does not exist, or a
`status.path` in a directory another user may write (`statuspaths.shared_directory`), is a
configuration error (exit 2, the key named as `cc_daemon.config` names keys). Then it
opens the journal, and a journal that cannot be opened at start is an error
too: running on with the whole survey in memory would lose it to a power cut.

It must never open the serial port or any other device (it only `stat`s the
port and reads sysfs), and never decide what is retried: a device that does not
exist yet (a USB adapter not plugged in) is fine here, the link waits for it.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import structlog

from cc_daemon.config import Settings
from cc_daemon.config.statuspaths import shared_directory
from cc_daemon.core.errors import ConfigError
from cc_daemon.daemon.simgate import backend_name, is_simulated
from cc_daemon.store import Journal, default_store_path

__all__ = ["check_paths", "open_journal", "serial_port_problem", "store_path_problem"]

_log = structlog.get_logger("cc_daemon.preflight")
_PREFIX = "cc-daemon: bad configuration: "
# No journal, and no spill file beside it, may live in these: they hold devices
# and the kernel's own files, not data.
_SYSTEM_TREES = (Path("/proc"), Path("/sys"), Path("/dev"))
_SYSFS_CHAR = Path("/sys/dev/char")


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISREG(mode):
        return "a regular file"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a file"


def _char_subsystem(rdev: int, sysfs: Path) -> str | None:
    """The kernel subsystem of a character device ("tty", "mem", ...), if sysfs says."""
    try:
        link = os.readlink(sysfs / f"{os.major(rdev)}:{os.minor(rdev)}" / "subsystem")
    except OSError:
        return None  # pseudo-terminals (/dev/pts/N) have no sysfs entry
    return Path(link).name


def serial_port_problem(port: str, *, sysfs: Path = _SYSFS_CHAR) -> str | None:
    """Why `port` can never be the autopilot's line, or None if it may be.

    A missing device may appear later (a USB adapter), so it is not a problem.
    """
    try:
        info = os.stat(port)
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        return "not a device path: a part of it is a file, not a directory"
    except (OSError, ValueError):
        return None  # no permission to look: opening it will say more, and be retried
    mode = info.st_mode
    if stat.S_ISCHR(mode):
        subsystem = _char_subsystem(info.st_rdev, sysfs)
        if subsystem is None or subsystem == "tty":
            return None
        return f"is a character device that is not a terminal ({subsystem} device)"
    return f"is {_kind(mode)}, not a terminal"


def _under(path: Path, tree: Path) -> bool:
    return path == tree or tree in path.parents


def store_path_problem(path: Path) -> str | None:
    """Why the journal can never be kept at `path`, or None if it may be."""
    text = os.fspath(path)
    if "\0" in text:
        return "must not contain a NUL character"
    absolute = Path(os.path.abspath(text))
    real = Path(os.path.realpath(text))
    for tree in _SYSTEM_TREES:
        if _under(absolute, tree) or _under(real, tree):
            return f"is under {tree}: that holds devices and kernel files, not a journal"
    try:
        info = os.stat(real)
    except (FileNotFoundError, NotADirectoryError):
        info = None  # the checks of its directory below say why
    except OSError as exc:
        return f"cannot be looked at: {exc.strerror or exc}"
    if info is not None and not stat.S_ISREG(info.st_mode):
        return f"is {_kind(info.st_mode)}; the journal must be a file"
    parent = real.parent
    if not parent.exists():
        return f"its directory {parent} does not exist"
    if not parent.is_dir():
        return f"its parent {parent} is not a directory"
    return None


def check_paths(settings: Settings) -> None:
    """Raise ConfigError, one line per problem, if a configured path can never work."""
    lines: list[str] = []
    problem = serial_port_problem(settings.serial.port)
    if problem is not None:
        lines.append(f"{settings.describe('serial.port')}: {problem}")
    store = settings.store.path
    problem = store_path_problem(store if store is not None else default_store_path())
    if problem is not None:
        if store is None:
            problem = f"the default {default_store_path()} {problem}"
        lines.append(f"{settings.describe('store.path')}: {problem}")
    status = settings.status.path
    problem = shared_directory(status) if settings.status.enabled and status else None
    if problem is not None:
        lines.append(
            f"{settings.describe('status.path')}: {problem}, so anyone could answer in the"
            " daemon's place; choose a directory only the daemon's user may write, or leave"
            " it unset"
        )
    if lines:
        raise ConfigError("\n".join(_PREFIX + line for line in lines))


def make_journal(settings: Settings) -> Journal:
    """The journal this configuration asks for, not yet opened: its file, its
    telemetry rate, and which winch its data come from (simulated or not)."""
    return Journal(
        settings.store.path or default_store_path(),
        telemetry_rate_hz=settings.store.telemetry_rate_hz,
        spill_dir=settings.store.spill_dir,
        file_mode=settings.store.file_mode_bits,
        winch_backend=backend_name(settings),
        simulated=is_simulated(settings),
    )


def open_journal(settings: Settings) -> Journal:
    """Open the configured journal, or raise ConfigError if it cannot be opened now.

    A file that can never be used (corrupt, another program's) is not an error:
    the journal leaves it untouched and starts a fresh one beside it, as it would
    mid-survey. A journal that fails later keeps its in-memory fallback.
    """
    journal = make_journal(settings)
    recovered = journal.open()
    health = journal.health()
    if not health.writable:
        journal.close()
        raise ConfigError(
            f"{_PREFIX}{settings.describe('store.path')}: the journal cannot be opened: "
            f"{health.last_error}"
        )
    for cast_id in recovered:
        _log.warning("cast left unfinished by a previous run", cast_id=cast_id)
    return journal
