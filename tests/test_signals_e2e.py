"""Signals against the daemon as a real subprocess (docs/signals.md).

The scenario of issue 9: a cast at 1 m/s to 5 m, SIGHUP 2 s in (the SSH session
that started the daemon closing, or `systemctl reload`). The cast must finish
and R-F arrive; the reload applies to the next cast; a bad file changes nothing.
Issue 19: SIGQUIT a clean stop; SIGUSR1, SIGUSR2 and every other signal that
ends a process by default never fatal, idle or mid-cast; SIGHUP and the stop
signals from the moment the entry point runs, long before the daemon is ready.
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
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.core.protocol import Ack, DepthReport, Finished, ProbePosition, ProbePositionRequest
from cc_daemon.ground.signals import HELD, IGNORED, signal_name
from tests.daemonkit import REPO, DaemonProcess, merge, station, toml_text
from tests.waitkit import DEADLINE_S, until, until_probe_down

# A daemon's start and one or two real-time casts each: minutes, not seconds, on a
# loaded machine (the suite's 60 s is for a test that hangs, not one that is slow).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]
MakeDaemon = Callable[..., DaemonProcess]
# 5 m at 1 m/s, 1 s at the bottom: R-F about 11 s after R-O.
FIVE_METRES = {"cast": {"target_depth_m": 5.0}}
STOPPING = "signal received: bringing the probe home, then exiting"


def events(daemon: DaemonProcess) -> list[str]:
    with sqlite3.connect(daemon.db) as db:
        return [kind for (kind,) in db.execute("SELECT kind FROM events ORDER BY id")]


def casts(daemon: DaemonProcess) -> list[tuple[object, ...]]:
    with sqlite3.connect(daemon.db) as db:
        return db.execute("SELECT id, outcome, planned_depth_m FROM casts ORDER BY id").fetchall()


def rewrite(daemon: DaemonProcess, **sections: object) -> None:
    daemon.config_path.write_text(toml_text(merge(daemon.config, sections)))


async def start_a_cast(daemon: DaemonProcess) -> None:
    """Send a station and return once the probe has left home (10 cm down, past the
    switch's 5 mm), descending: mid-cast."""
    assert daemon.port is not None
    await daemon.port.send(station())
    await daemon.expect(Ack, DEADLINE_S)
    await until_probe_down(daemon, 100)


async def until_logged(daemon: DaemonProcess, event: str, count: int = 1) -> None:
    """Return once the daemon has logged `event` `count` times: it has acted on the
    signal sent before, so the next one comes after it, whatever the machine's load."""
    await until(lambda: len(logged(daemon, event)) >= count, f"{count} x {event!r} logged")


async def test_sighup_mid_cast_reloads_and_the_cast_completes(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon(FIVE_METRES)
    port = await daemon.start_and_connect(DEADLINE_S)
    await start_a_cast(daemon)
    # A file that no longer validates: refused, with the lines --config prints.
    rewrite(daemon, cast={"bogus": 1})
    daemon.send_signal(signal.SIGHUP)
    await until_logged(daemon, "reload refused: keeping the configuration in use")
    daemon.check_alive()
    # A valid one: the next cast goes to 2 m; the port needs a restart.
    rewrite(daemon, cast={"target_depth_m": 2.0}, serial={"port": "/dev/ttyNEW"})
    daemon.send_signal(signal.SIGHUP)
    finished = await daemon.expect(Finished, DEADLINE_S)
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    daemon.check_alive()
    # The next station (far from the first): planned with the reloaded depth.
    await port.send(station(lat_e7=404606308, timestamp=200))
    await daemon.expect(Ack, DEADLINE_S)
    await daemon.expect(Finished, DEADLINE_S)
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit(DEADLINE_S) == 0
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
    port = await daemon.start_and_connect(DEADLINE_S)
    await start_a_cast(daemon)
    await until_probe_down(daemon, 1000)  # a second's ascent to be interrupted
    daemon.send_signal(signal.SIGTERM)
    await until_logged(daemon, STOPPING)
    ignored = "SIGHUP during shutdown: ignored; the shutdown goes on"
    daemon.send_signal(signal.SIGHUP)
    await until_logged(daemon, ignored)
    # An SSH session closing goes on sending SIGHUP, through the ascent and to the
    # process's very last instant, when the interpreter's exit gives each Python
    # handler its default action back.
    assert await sighup_until_exit(daemon) == 0
    finished = await daemon.expect(Finished, DEADLINE_S)  # read since, in order
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    assert casts(daemon) == [(1, "aborted", 5.0)]
    await port.close()


async def sighup_until_exit(daemon: DaemonProcess) -> int:
    """SIGHUP the daemon every millisecond or so until it exits; its exit status."""
    assert daemon.proc is not None
    deadline = time.monotonic() + DEADLINE_S
    while daemon.proc.poll() is None:
        assert time.monotonic() < deadline, "the daemon did not exit"
        daemon.send_signal(signal.SIGHUP)  # nothing once it has exited (Popen polls first)
        await asyncio.sleep(0.001)
    return daemon.proc.returncode


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
    await daemon.connect()
    await daemon.wait_answering(DEADLINE_S)
    await start_a_cast(daemon)
    os.close(master)  # the session ends: SIGHUP, then EIO on every write
    closed = time.monotonic()
    # The cast goes on: a depth report sent after the terminal went away.
    report = await daemon.expect(DepthReport, DEADLINE_S)
    while report is not None and report.time <= closed:
        report = await daemon.expect(DepthReport, DEADLINE_S)
    finished = await daemon.expect(Finished, DEADLINE_S)
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    daemon.check_alive()
    # The housekeeping tick journals the loss of the log's stream.
    await until(lambda: "log_output_lost" in events(daemon), "log_output_lost journaled")
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit(DEADLINE_S) == 0
    assert b"cc-daemon started" in seen
    assert casts(daemon) == [(1, "completed", 5.0)]


def caught(pid: int, signum: int) -> bool:
    """Whether process `pid` has a handler for `signum` (the kernel's SigCgt mask)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    return False


def wait_held(daemon: DaemonProcess, timeout: float = DEADLINE_S) -> None:
    """Return the moment the daemon holds its signals: its entry point's first lines.
    (The last of `HELD` is caught last; SIGINT is the interpreter's own from its start.)"""
    assert daemon.proc is not None
    deadline = time.monotonic() + timeout
    while not caught(daemon.proc.pid, HELD[-1]):
        assert daemon.proc.poll() is None, daemon.log_text()
        assert time.monotonic() < deadline, "the signal was never caught"


def logged(daemon: DaemonProcess, event: str) -> list[dict[str, object]]:
    return [e for e in daemon.log_events() if e.get("event") == event]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGQUIT, signal.SIGINT])
async def test_a_stop_before_ready_is_a_clean_exit_0(make_daemon: MakeDaemon, signum: int) -> None:
    daemon = make_daemon()
    daemon.start()
    wait_held(daemon)  # the entry point's first lines: pydantic not yet imported
    daemon.send_signal(signum)
    assert await daemon.wait_exit(DEADLINE_S) == 0
    [stopped] = logged(
        daemon, "stop requested before the daemon was ready: exiting; nothing was opened"
    )
    assert stopped["signals"] == [signal_name(signum)]
    assert not daemon.db.exists()  # nothing opened: no journal, no port, the probe never moved


async def test_sighup_in_the_first_second_waits_for_the_loop_then_reloads(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon()
    daemon.start()
    wait_held(daemon)
    for _ in range(20):  # the SSH session closing, again and again, while it starts
        daemon.send_signal(signal.SIGHUP)
        await asyncio.sleep(0.005)
    await daemon.connect()
    await daemon.wait_answering(DEADLINE_S)
    await until_logged(daemon, "configuration reloaded: unchanged")
    reloads = logged(daemon, "configuration reloaded: unchanged")
    assert 1 <= len(reloads) <= 20  # the held ones coalesced into one reload
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit(DEADLINE_S) == 0


async def test_sigquit_mid_cast_is_a_clean_stop(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()  # 3 m at 1 m/s
    await daemon.start_and_connect(DEADLINE_S)
    await start_a_cast(daemon)
    daemon.send_signal(signal.SIGQUIT)
    await until_logged(daemon, STOPPING)
    daemon.send_signal(signal.SIGQUIT)  # a repeat changes nothing
    finished = await daemon.expect(Finished, DEADLINE_S)
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    assert await daemon.wait_exit(DEADLINE_S) == 0
    assert casts(daemon) == [(1, "aborted", 3.0)]
    assert logged(daemon, STOPPING)[0]["signal"] == "SIGQUIT"
    [repeat] = logged(daemon, "already shutting down; Ctrl-C twice stops at once")
    assert repeat["signal"] == "SIGQUIT"


NEVER_FATAL = (signal.SIGUSR2, *IGNORED, signal.SIGUSR1)
SPARE = "SIGUSR2 received: it has no action (docs/signals.md)"


async def test_no_other_signal_ends_the_daemon_idle_or_mid_cast(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()  # 3 m at 1 m/s
    port = await daemon.start_and_connect(DEADLINE_S)
    for signum in NEVER_FATAL:  # idle: each of these ended the daemon by default
        daemon.send_signal(signum)
    # The kernel hands pending signals over lowest number first: wait for each.
    await until_logged(daemon, "status (SIGUSR1)")
    await until_logged(daemon, SPARE)
    await until(lambda: ignored_names(daemon) >= {signal_name(s) for s in IGNORED}, "all ignored")
    await port.send(ProbePositionRequest(5))
    assert await daemon.expect(ProbePosition, DEADLINE_S) is not None
    assert ignored_names(daemon) == {signal_name(s) for s in IGNORED}
    [idle] = logged(daemon, "status (SIGUSR1)")
    assert "no cast, probe at 0.00 m" in str(idle["summary"])
    await start_a_cast(daemon)
    for signum in NEVER_FATAL:  # mid-cast: the cast goes on to its end
        daemon.send_signal(signum)
    finished = await daemon.expect(Finished, DEADLINE_S)
    assert finished is not None and finished.message.depth_mm == 0  # type: ignore[union-attr]
    daemon.check_alive()
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit(DEADLINE_S) == 0
    assert casts(daemon) == [(1, "completed", 3.0)]
    _, cast_line = (str(e["summary"]) for e in logged(daemon, "status (SIGUSR1)"))
    assert "link up on" in cast_line and "cast 1 descending at" in cast_line, cast_line
    assert "of 3.00 m; winch sim moving, not home, no fault; journal writable" in cast_line
    assert len(logged(daemon, SPARE)) == 2


def ignored_names(daemon: DaemonProcess) -> set[object]:
    return {e["signal"] for e in logged(daemon, "signal ignored: it never stops the daemon")}
