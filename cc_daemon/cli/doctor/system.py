"""The machine as `doctor` sees it: every path under a root (`/`, or a fake one in
tests), the service user's identity from the root's passwd and group files, and
whether that user may read and write a file, decided from the mode bits as the
kernel would (no ACLs). It only reads; it never changes the machine.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from cc_daemon.ground.clocksync import ClockSync, clock_sync

SERVICE = "cc-daemon"
UNIT_PATH = "/etc/systemd/system/cc-daemon.service"
DEFAULT_GROUPS = ("dialout", "gpio", "spi")


def _systemctl_state() -> str | None:
    """`systemctl is-active cc-daemon`, or None where systemd cannot be asked."""
    systemctl = shutil.which("systemctl")
    if systemctl is None or not os.path.isdir("/run/systemd/system"):
        return None
    try:
        result = subprocess.run(
            [systemctl, "is-active", SERVICE],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return result.stdout.strip() or None


@dataclass(frozen=True, slots=True)
class Identity:
    user: str
    uid: int
    gids: frozenset[int]


def _find_spec(module: str) -> bool:
    from importlib.util import find_spec

    try:
        return find_spec(module) is not None
    except (ImportError, ValueError):
        return False


@dataclass
class System:
    """What the checks read. Tests give a fake root and fake kernel answers."""

    root: Path = Path("/")
    statvfs: Callable[[str], os.statvfs_result] = os.statvfs
    clock: Callable[[], ClockSync] = clock_sync
    service_state: Callable[[], str | None] | None = None
    # Whether a library is installed where the doctor runs (tests plant missing ones).
    installed: Callable[[str], bool] = field(default=_find_spec)
    _unit: dict[str, str] = field(default_factory=dict)

    def path(self, path: str | Path) -> Path:
        """`path` (absolute on the target machine) under the root."""
        path = Path(path)
        if self.root == Path("/"):
            return path
        return self.root / path.relative_to(path.anchor) if path.is_absolute() else path

    @property
    def image(self) -> bool:
        """Whether the checks read a system image (`--root`), not the running system."""
        return self.root != Path("/")

    def state(self) -> str | None:
        if self.service_state is not None:
            return self.service_state()
        return _systemctl_state() if self.root == Path("/") else None

    def read(self, path: str) -> str | None:
        try:
            return self.path(path).read_text(errors="replace")
        except OSError:
            return None

    def unit_setting(self, key: str, default: str) -> str:
        """A [Service] setting of the installed unit (its last value), else `default`."""
        if not self._unit:
            for line in (self.read(UNIT_PATH) or "").splitlines():
                name, sep, value = line.strip().partition("=")
                if sep and not name.startswith(("#", ";")):
                    self._unit[name.strip()] = value.strip()
        return self._unit.get(key, default)

    def service_identity(self) -> Identity | None:
        """The unit's User=, with Group= and SupplementaryGroups= (None: no such user)."""
        user = self.unit_setting("User", SERVICE)
        users = {f[0]: f for f in _fields(self.read("/etc/passwd"))}
        groups = {f[0]: f for f in _fields(self.read("/etc/group"))}
        if user not in users or len(users[user]) < 4:
            return None
        uid, gid = int(users[user][2]), int(users[user][3])
        names = [self.unit_setting("Group", "")]
        names += self.unit_setting("SupplementaryGroups", " ".join(DEFAULT_GROUPS)).split()
        gids = {gid} | {int(groups[n][2]) for n in names if n in groups}
        # Groups that list the user as a member count too (usermod -aG).
        gids |= {int(f[2]) for f in groups.values() if len(f) > 3 and user in f[3].split(",")}
        return Identity(user, uid, frozenset(gids))


def _fields(text: str | None) -> list[list[str]]:
    return [line.split(":") for line in (text or "").splitlines() if line.count(":") >= 2]


def may(who: Identity, st: os.stat_result, want: int) -> bool:
    """Whether `who` has the `want` bits (4 read, 2 write, 1 execute) on a file."""
    if who.uid == 0:
        return True
    if st.st_uid == who.uid:
        shift = 6
    elif st.st_gid in who.gids:
        shift = 3
    else:
        shift = 0
    return (stat.S_IMODE(st.st_mode) >> shift) & want == want


def describe_owner(st: os.stat_result) -> str:
    return f"mode {stat.S_IMODE(st.st_mode):04o}, owner {st.st_uid}:{st.st_gid}"


def resolve(system: System, path: Path) -> tuple[Path, str]:
    """Follow symlinks from `path` (under the root): the real file, and the device's
    name as the target machine knows it (the last name inside the root).

    An absolute link target is looked up under the root; one that is not there is
    taken as it is (a fake root whose ttyAMA0 stands for a real pty)."""
    current = system.path(path)
    name = current.name
    for _ in range(40):
        if not current.is_symlink():
            break
        target = Path(os.readlink(current))
        if not target.is_absolute():
            current = current.parent / target
        elif system.path(target).exists() or system.path(target).is_symlink():
            current = system.path(target)
        else:
            return Path(os.path.realpath(target)), name
        name = current.name
    return Path(os.path.realpath(current)), name
