"""Start-up checks: a port or a journal path that can never work is exit 2, naming the key."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.daemon.preflight import (
    check_paths,
    open_journal,
    serial_port_problem,
    store_path_problem,
)
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import REPO
from tests.waitkit import DEADLINE_S

PREFIX = "cc-daemon: bad configuration: "


def test_a_terminal_and_a_missing_device_are_fine(tmp_path: Path) -> None:
    pty = PtyPair(tmp_path / "ttyAP")
    try:
        assert serial_port_problem(str(pty.path)) is None  # a symlink to /dev/pts/N
    finally:
        pty.close()
    assert serial_port_problem("/dev/ttyUSB7-not-plugged-in") is None  # may appear later


def test_things_that_are_not_terminals(tmp_path: Path) -> None:
    regular = tmp_path / "capture.bin"
    regular.write_bytes(b"PS")
    assert serial_port_problem(str(tmp_path)) == "is a directory, not a terminal"
    assert serial_port_problem(str(regular)) == "is a regular file, not a terminal"
    assert serial_port_problem("/dev/null") == (
        "is a character device that is not a terminal (mem device)"
    )
    assert serial_port_problem(str(regular / "x")) is not None


@pytest.mark.parametrize(
    ("path", "expected"),
    [
        ("/dev/null", "is under /dev"),
        ("/proc/self/status", "is under /proc"),
        ("/sys/kernel/x.db", "is under /sys"),
        ("/nonexistent/dir/x.db", "its directory /nonexistent/dir does not exist"),
        ("survey\0.db", "must not contain a NUL character"),
    ],
)
def test_journal_paths_that_can_never_work(path: str, expected: str) -> None:
    problem = store_path_problem(Path(path))
    assert problem is not None and problem.startswith(expected), problem


def test_journal_path_kinds(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    os.mkfifo(tmp_path / "fifo")
    assert store_path_problem(tmp_path) == "is a directory; the journal must be a file"
    assert store_path_problem(tmp_path / "fifo") == "is a named pipe; the journal must be a file"
    assert store_path_problem(tmp_path / "file" / "x.db") == (
        f"its parent {tmp_path / 'file'} is not a directory"
    )
    assert store_path_problem(tmp_path / "new.db") is None
    assert store_path_problem(tmp_path / "file") is None
    # A symlink into /proc is as bad as the path itself.
    (tmp_path / "link.db").symlink_to("/proc/self/status")
    assert str(store_path_problem(tmp_path / "link.db")).startswith("is under /proc")


def test_check_paths_names_the_keys_and_their_sources(tmp_path: Path) -> None:
    settings = load_settings(
        None,
        {"serial": {"port": "/dev/null"}, "store": {"path": tmp_path}},
        env={},
        search_paths=(),
    )
    with pytest.raises(ConfigError) as caught:
        check_paths(settings)
    assert str(caught.value).splitlines() == [
        f'{PREFIX}serial.port = "/dev/null" (from --port): '
        "is a character device that is not a terminal (mem device)",
        f'{PREFIX}store.path = "{tmp_path}" (from --db): '
        "is a directory; the journal must be a file",
    ]


def test_a_journal_that_cannot_be_opened_at_start_is_a_configuration_error(
    tmp_path: Path,
) -> None:
    (tmp_path / "x.db-wal").mkdir()  # SQLite cannot make its write-ahead log: I/O error
    settings = load_settings(None, {"store": {"path": tmp_path / "x.db"}}, env={}, search_paths=())
    with pytest.raises(ConfigError, match=r"store\.path = .* the journal cannot be opened"):
        open_journal(settings)


def run_daemon(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
    env["PYTHONPATH"] = str(REPO)
    # The simulated winch (the default backend) is what these runs drive; asked for
    # in so many words, so that the checks under test are the ones that refuse.
    env["CC_DAEMON_WINCH__SIM__ALLOW_OUTSIDE_SIMULATION"] = "true"
    return subprocess.run(
        [sys.executable, "-m", "cc_daemon", "--log-format", "json", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=DEADLINE_S,
        check=False,
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "key"),
    [
        (["--port", "/dev/null"], "serial.port"),
        (["--port", "{tmp}"], "serial.port"),
        (["--port", "{regular}"], "serial.port"),
        (["--db", "/nonexistent/dir/x.db"], "store.path"),
        (["--db", "{tmp}"], "store.path"),
        (["--db", "/dev/null"], "store.path"),
        (["--db", "/proc/self/status"], "store.path"),
    ],
)
def test_the_daemon_exits_2_before_opening_anything(
    tmp_path: Path, args: list[str], key: str
) -> None:
    regular = tmp_path / "capture.bin"
    regular.write_bytes(b"")
    args = [a.format(tmp=tmp_path, regular=regular) for a in args]
    if "--db" not in args:
        args += ["--db", str(tmp_path / "journal.db")]
    if "--port" not in args:
        args += ["--port", str(tmp_path / "ttyNotThere")]
    done = run_daemon(tmp_path, *args)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith(f"{PREFIX}{key} = "), done.stderr
    assert not (tmp_path / "journal.db").exists()


@pytest.mark.slow
def test_the_daemon_exits_2_when_the_journal_cannot_be_opened(tmp_path: Path) -> None:
    (tmp_path / "x.db-wal").mkdir()
    done = run_daemon(tmp_path, "--db", str(tmp_path / "x.db"), "--port", str(tmp_path / "tty"))
    assert done.returncode == 2, done.stderr
    assert (
        f'{PREFIX}store.path = "{tmp_path / "x.db"}" (from --db): the journal cannot be opened'
        in (done.stderr)
    )
