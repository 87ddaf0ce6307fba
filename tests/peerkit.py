"""Test kit for the sockets' peers: real second users, real sockets.

`Users` (`session_users`, for a session fixture) makes users and groups with
useradd and groupadd, as root, and removes them at the end of the session;
elsewhere a test that needs one is skipped, saying why. `as_user` runs
`tests/as_user.py` as one of them: `cc-daemon ARGS`, an impostor answering on a
socket, or a client holding connections. `entered_dir` is a directory other
users may enter (pytest's own temporary tree is private to root).
"""

from __future__ import annotations

import contextlib
import grp
import os
import pwd
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class User:
    name: str
    uid: int
    gid: int
    groups: tuple[int, ...] = ()

    @property
    def gids(self) -> str:
        return ",".join(str(g) for g in (self.gid, *self.groups))


@dataclass
class Users:
    """Users and groups made for this session (as root), removed at its end."""

    prefix: str = field(default_factory=lambda: f"ccdt{os.getpid() % 100000}")
    made_users: list[str] = field(default_factory=list)
    made_groups: list[str] = field(default_factory=list)

    def _run(self, *command: str) -> None:
        if os.geteuid() != 0:
            pytest.skip("needs a second user: run as root to make one with useradd")
        if shutil.which(command[0]) is None:
            pytest.skip(f"needs a second user: {command[0]} is not installed")
        done = subprocess.run(command, capture_output=True, text=True, check=False, timeout=60)
        if done.returncode != 0:
            pytest.skip(f"needs a second user: {' '.join(command)}: {done.stderr.strip()}")

    def group(self, suffix: str) -> int:
        name = f"{self.prefix}{suffix}"
        try:
            return grp.getgrnam(name).gr_gid
        except KeyError:
            self._run("groupadd", "--system", name)
            self.made_groups.append(name)
            return grp.getgrnam(name).gr_gid

    def user(self, suffix: str, *, groups: tuple[int, ...] = ()) -> User:
        """A user named after `suffix` (made once), listed in `groups` in /etc/group
        and given them as supplementary groups when acting."""
        name = f"{self.prefix}{suffix}"
        try:
            entry = pwd.getpwnam(name)
        except KeyError:
            extra = ["-G", ",".join(grp.getgrgid(g).gr_name for g in groups)] if groups else []
            self._run(
                "useradd", "--system", "--no-create-home", "--shell", "/usr/sbin/nologin",
                "--user-group", *extra, name,
            )  # fmt: skip
            self.made_users.append(name)
            entry = pwd.getpwnam(name)
        return User(name, entry.pw_uid, entry.pw_gid, groups)

    def remove(self) -> None:
        for name in self.made_users:
            subprocess.run(["userdel", name], capture_output=True, check=False, timeout=60)
        for name in self.made_groups:
            subprocess.run(["groupdel", name], capture_output=True, check=False, timeout=60)


def as_user(
    user: User, action: str, *args: str, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """Run tests/as_user.py ACTION ARGS as `user` to its end (30 s at most)."""
    return subprocess.run(
        as_user_command(user, action, *args),
        capture_output=True,
        text=True,
        check=False,
        timeout=30,
        env=as_user_env(env),
        cwd="/",
    )


@contextlib.contextmanager
def acting(user: User, action: str, *args: str) -> Iterator[str]:
    """tests/as_user.py ACTION ARGS as `user` in the background (`serve`, `hold`):
    its `ready` line once it is, then stopped by closing its stdin."""
    proc = subprocess.Popen(
        as_user_command(user, action, *args),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=as_user_env(),
        cwd="/",
    )
    assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
    try:
        ready = proc.stdout.readline()
        assert ready.startswith("ready"), proc.stderr.read()
        yield ready
    finally:
        proc.stdin.close()
        proc.wait(30)
        proc.stdout.close()
        proc.stderr.close()


def as_user_command(user: User, action: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "tests.as_user", str(user.uid), user.gids, action, *args]


def as_user_env(env: dict[str, str] | None = None) -> dict[str, str]:
    base = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "TMPDIR")}
    return {**base, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1", **(env or {})}


@contextlib.contextmanager
def session_users() -> Iterator[Users]:
    """Users made on demand, removed at the end (a session fixture's body)."""
    made = Users()
    try:
        yield made
    finally:
        made.remove()


@contextlib.contextmanager
def entered_dir() -> Iterator[Path]:
    """A directory (0755, root's) that other users may enter, removed afterwards."""
    top = Path(tempfile.mkdtemp(prefix="cc-daemon-sockets-"))
    top.chmod(0o755)
    try:
        yield top
    finally:
        shutil.rmtree(top, ignore_errors=True)
