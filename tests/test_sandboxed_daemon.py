"""The daemon inside (most of) the unit's sandbox, without systemd as PID 1.

systemd is not PID 1 on the CI machine, so `systemd-run -p ...` cannot start the
unit's sandbox there. This test rebuilds the parts that could break the daemon
from ordinary tools and runs a whole cast inside them:
- no capabilities at all and no new privileges (`setpriv`: CapabilityBoundingSet=,
  AmbientCapabilities=, NoNewPrivileges=);
- no network (`unshare --net`: PrivateNetwork=);
- the system calls of @privileged, @resources and @clock failing with EPERM, as
  the unit's SystemCallFilter= and ProtectClock= make them (libseccomp, the
  library systemd uses: tests/seccomp_exec.py), the list taken from this
  machine's `systemd-analyze syscall-filter`;
- the whole file system read-only but the state and runtime directories
  (`unshare --mount`, a read-only remount of /: ProtectSystem=strict);
- UMask=0027, and systemd's contract: $STATE_DIRECTORY for the journal,
  $RUNTIME_DIRECTORY for the status socket, READY=1 on $NOTIFY_SOCKET.
The rest (DevicePolicy=, ProtectHome= (this machine's Python lives under /root),
the dedicated user, the Protect*/Restrict* kernel settings) needs systemd: see
docs/deployment.md for the check on the Pi.
"""

from __future__ import annotations

import asyncio
import errno
import os
import shutil
import socket
import stat
import subprocess
import sys
import time
from collections.abc import Callable
from ctypes.util import find_library
from functools import cache
from pathlib import Path

import pytest

from cc_daemon.cli.status.client import read_status
from cc_daemon.core.protocol import Finished
from tests.daemonkit import (
    REPO,
    START_S,
    WAIT_S,
    DaemonProcess,
    station,
    toml_text,
)

TOOLS = ("unshare", "setpriv", "systemd-analyze")
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(os.geteuid() != 0, reason="needs root for unshare --net and setpriv"),
    pytest.mark.skipif(
        any(shutil.which(t) is None for t in TOOLS) or find_library("seccomp") is None,
        reason=f"needs {', '.join(TOOLS)} and libseccomp",
    ),
]


@cache
def syscalls(group: str) -> frozenset[str]:
    """The calls of a systemd syscall group, nested groups expanded."""
    out = subprocess.run(
        ["systemd-analyze", "syscall-filter", "--no-pager", group],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    names: set[str] = set()
    for line in out.splitlines()[1:]:
        token = line.strip()
        if not token or token.startswith("#"):
            continue
        names |= syscalls(token) if token.startswith("@") else {token}
    return frozenset(names)


# In a private mount namespace: the two writable directories become mounts of
# their own, then the root is remounted read-only (ProtectSystem=strict), then the
# capabilities go.
_SANDBOX = (
    'mount --bind "$STATE_DIRECTORY" "$STATE_DIRECTORY"'
    ' && mount --bind "$RUNTIME_DIRECTORY" "$RUNTIME_DIRECTORY"'
    " && mount -o remount,bind,ro /"
    " && umask 0027"
    ' && exec setpriv --inh-caps=-all --bounding-set=-all --no-new-privs -- "$@"'
)


def sandbox_prefix() -> list[str]:
    # As the unit: @privileged and @resources denied, but adjtimex allowed back (a
    # read needs no capability, and none is granted, so it can never set the clock).
    denied = (syscalls("@privileged") | syscalls("@resources") | syscalls("@clock")) - {
        "adjtimex",
        "clock_adjtime",
    }
    assert {"setuid", "setrlimit", "clock_settime", "chown"} <= denied
    return [
        "unshare",
        "--net",
        "--mount",
        "--",
        "sh",
        "-c",
        _SANDBOX,
        "sh",
        sys.executable,
        str(REPO / "tests" / "seccomp_exec.py"),
        ",".join(sorted(denied)),
        "--",
    ]


def test_the_sandbox_is_real(tmp_path: Path) -> None:
    state, runtime = tmp_path / "state", tmp_path / "run"
    state.mkdir()
    runtime.mkdir()
    probe = (
        "import os, socket, sys\n"
        "open(os.environ['STATE_DIRECTORY'] + '/ok', 'w').close()\n"
        "for what in (lambda: open(sys.argv[1], 'w'), lambda: os.setpriority(0, 0, 5),\n"
        "             lambda: socket.create_connection(('127.0.0.1', 9))):\n"
        "    try:\n"
        "        what()\n"
        "    except OSError as exc:\n"
        "        print(exc.errno)\n"
    )
    result = subprocess.run(
        [*sandbox_prefix(), sys.executable, "-c", probe, str(tmp_path / "outside")],
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "STATE_DIRECTORY": str(state), "RUNTIME_DIRECTORY": str(runtime)},
    )
    assert result.returncode == 0, result.stderr
    # Read-only file system, a denied system call, no network.
    assert result.stdout.split() == [str(errno.EROFS), str(errno.EPERM), str(errno.ENETUNREACH)]
    assert (state / "ok").exists() and not (tmp_path / "outside").exists()


async def test_a_whole_cast_inside_the_sandbox(make_daemon: Callable[..., DaemonProcess]) -> None:
    daemon = make_daemon()
    del daemon.config["store"]  # the journal goes where systemd says: $STATE_DIRECTORY
    daemon.config_path.write_text(toml_text(daemon.config))
    state, runtime = daemon.tmp / "state", daemon.tmp / "run"
    state.mkdir(mode=0o750)
    runtime.mkdir(mode=0o750)
    notify_path = daemon.tmp / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as notify:
        notify.bind(str(notify_path))
        notify.setblocking(False)
        daemon.start(
            prefix=sandbox_prefix(),
            env={
                "STATE_DIRECTORY": str(state),
                "RUNTIME_DIRECTORY": str(runtime),
                "NOTIFY_SOCKET": str(notify_path),
            },
        )
        port = await daemon.connect()
        await daemon.wait_answering(START_S)
        loop = asyncio.get_running_loop()
        ready = await asyncio.wait_for(loop.sock_recv(notify, 4096), WAIT_S)
        assert b"READY=1" in ready

        await port.send(station())
        await daemon.expect(Finished)
        deadline = time.monotonic() + WAIT_S  # the status counts the cast once it has ended
        while (doc := await asyncio.to_thread(read_status, runtime / "status.sock"))["counters"][
            "casts_completed"
        ] != 1:
            assert time.monotonic() < deadline, doc
            await asyncio.sleep(0.05)

    assert "seccomp_exec: " in daemon.log_text() and "system calls denied" in daemon.log_text()
    assert not (daemon.tmp / "cc-daemon.db").exists()  # nothing written beside the config
    assert doc["link"]["up"] is True and doc["counters"]["casts_completed"] == 1
    assert doc["journal"]["path"] == str(state / "cc-daemon.db")
    assert doc["journal"]["writable"] is True
    # The kernel's view of the clock (adjtimex) is readable in the sandbox.
    assert doc["clock"]["source"] == "adjtimex"
    assert stat.S_IMODE((runtime / "status.sock").stat().st_mode) == 0o660
    assert stat.S_IMODE((state / "cc-daemon.db").stat().st_mode) == 0o640  # UMask=0027
    problems = [
        e for e in daemon.log_events() if e.get("level") in ("warning", "error", "critical")
    ]
    # The one expected: the test's simulated winch, allowed by name, is announced.
    announced = [e for e in problems if str(e.get("event")).startswith("SIMULATED WINCH")]
    assert len(announced) == 1 and announced[0]["level"] == "critical"
    assert [e for e in problems if e not in announced] == []
    daemon.send_signal()
    assert await daemon.wait_exit() == 0
