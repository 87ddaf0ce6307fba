"""SIGHUP against the daemon as a real subprocess: never fatal, never mid-cast, a reload.

The scenario of issue 9: a cast at 1 m/s to 5 m, SIGHUP 2 s in (the SSH session
that started the daemon closing, or `systemctl reload`). The cast must finish
and R-F arrive; the reload applies to the next cast; a bad file changes nothing.
"""

from __future__ import annotations

import asyncio
import fcntl
import os
import signal
import sqlite3
import subprocess
import sys
import termios
import threading
from collections.abc import Callable

import pytest

from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.core.protocol import Ack, DepthReport, Finished
from tests.daemonkit import REPO, DaemonProcess, merge, station, toml_text

pytestmark = pytest.mark.slow
MakeDaemon = Callable[..., DaemonProcess]
# 5 m at 1 m/s, 1 s at the bottom: R-F about 11 s after R-O.
FIVE_METRES = {"cast": {"target_depth_m": 5.0}}


def events(daemon: DaemonProcess) -> list[str]:
    with sqlite3.connect(daemon.db) as db:
        return [kind for (kind,) in db.execute("SELECT kind FROM events ORDER BY id")]


def casts(daemon: DaemonProcess) -> list[tuple[object, ...]]:
    with sqlite3.connect(daemon.db) as db:
        return db.execute("SELECT id, outcome, planned_depth_m FROM casts ORDER BY id").fetchall()


def rewrite(daemon: DaemonProcess, **sections: object) -> None:
    daemon.config_path.write_text(toml_text(merge(daemon.config, sections)))


async def test_sighup_mid_cast_reloads_and_the_cast_completes(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon(FIVE_METRES)
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack, 2)
    await asyncio.sleep(2.0)
    # A file that no longer validates: refused, with the lines --config prints.
    rewrite(daemon, cast={"bogus": 1})
    daemon.send_signal(signal.SIGHUP)
    await asyncio.sleep(0.5)
    daemon.check_alive()
    # A valid one: the next cast goes to 2 m; the port needs a restart.
    rewrite(daemon, cast={"target_depth_m": 2.0}, serial={"port": "/dev/ttyNEW"})
    daemon.send_signal(signal.SIGHUP)
    finished = await daemon.expect(Finished, 20)
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    daemon.check_alive()
    # The next station (far from the first): planned with the reloaded depth.
    await port.send(station(lat_e7=404606308, timestamp=200))
    await daemon.expect(Ack, 2)
    await daemon.expect(Finished, 15)
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    assert casts(daemon) == [(1, "completed", 5.0), (2, "completed", 2.0)]
    logged = daemon.log_events()
    refused = [
        e for e in logged if e.get("event") == "reload refused: keeping the configuration in use"
    ]
    assert len(refused) == 1
    # The very lines --config prints for that file at start.
    rewrite(daemon, cast={"bogus": 1})
    with pytest.raises(ConfigError) as at_start:
        load_settings(daemon.config_path, env={}, search_paths=())
    assert refused[0]["problems"] == str(at_start.value).splitlines()
    assert "cast.bogus" in refused[0]["problems"][0]
    restart = [e for e in logged if str(e.get("event", "")).startswith("reload: this key needs")]
    assert [(e["key"], e["in_file"]) for e in restart] == [("serial.port", "/dev/ttyNEW")]
    kinds = events(daemon)
    assert kinds.count("config_reload_refused") == 1
    assert kinds.count("config_reloaded") == 1


async def test_sighup_during_a_sigterm_shutdown_does_not_kill_it(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon(FIVE_METRES)
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack, 2)
    await asyncio.sleep(2.0)
    daemon.send_signal(signal.SIGTERM)
    await asyncio.sleep(0.2)
    daemon.send_signal(signal.SIGHUP)
    await asyncio.sleep(0.2)
    daemon.send_signal(signal.SIGHUP)
    finished = await daemon.expect(Finished, 15)
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    assert await daemon.wait_exit() == 0
    assert casts(daemon) == [(1, "aborted", 5.0)]
    await port.close()


def start_on_a_terminal(daemon: DaemonProcess) -> int:
    """Start the daemon with a pty as its controlling terminal and its stdout and
    stderr; return the pty's master (close it to end the "session")."""
    master, slave = os.openpty()
    env = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
    env["PYTHONPATH"] = str(REPO)
    daemon.proc = subprocess.Popen(
        [sys.executable, "-m", "cc_daemon", "--config", str(daemon.config_path)],
        stdin=subprocess.DEVNULL,
        stdout=slave,
        stderr=slave,
        env=env,
        cwd=daemon.tmp,
        start_new_session=True,
        preexec_fn=_take_terminal,  # noqa: PLW1509 - the child has one thread
    )
    os.close(slave)
    return master


def _take_terminal() -> None:
    # In the child: become a session leader whose controlling terminal is the pty
    # on fds 1 and 2, as a daemon started from an SSH session is.
    fcntl.ioctl(1, termios.TIOCSCTTY, 0)


async def test_the_terminal_going_away_mid_cast_changes_nothing(make_daemon: MakeDaemon) -> None:
    """The SSH session closes: the kernel sends SIGHUP, and stderr now fails with EIO."""
    daemon = make_daemon(FIVE_METRES)
    master = start_on_a_terminal(daemon)
    seen = bytearray()

    def read_terminal() -> None:  # as a terminal would, until it goes away
        try:
            while chunk := os.read(master, 4096):
                seen.extend(chunk)
        except OSError:
            pass

    reader = threading.Thread(target=read_terminal, daemon=True)
    reader.start()
    port = await daemon.connect()
    await daemon.wait_answering()
    await port.send(station())
    await daemon.expect(Ack, 2)
    await asyncio.sleep(2.0)
    os.close(master)  # the session ends: SIGHUP, then EIO on every write
    reports_after = await daemon.collect(2.0)
    assert any(isinstance(r.message, DepthReport) for r in reports_after)
    finished = await daemon.expect(Finished, 15)
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    daemon.check_alive()
    for _ in range(25):  # the housekeeping tick reports it within a second or so
        if "log_output_lost" in events(daemon):
            break
        await asyncio.sleep(0.2)
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    assert b"cc-daemon started" in seen
    assert casts(daemon) == [(1, "completed", 5.0)]
    assert "log_output_lost" in events(daemon)
