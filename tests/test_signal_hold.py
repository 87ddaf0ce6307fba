"""The signals held from the first instruction (`cc_daemon.ground.signals`) and the
daemon's table (`cc_daemon.daemon.signals`), in process: real signals raised at
this process, real handlers; the subprocess end-to-end side is test_signals_e2e.py.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

import pytest
import structlog

from cc_daemon.cli.app import main
from cc_daemon.core.status import DaemonStatus
from cc_daemon.core.winch.status import WinchStatus
from cc_daemon.daemon.signals import DaemonSignals, status_line
from cc_daemon.daemon.status_report import StatusInputs
from cc_daemon.ground.signals import HELD, IGNORED, LEFT_ALONE, SignalHold, signal_name
from cc_daemon.store import JournalHealth
from tests.daemonkit import REPO
from tests.waitkit import DEADLINE_S


@pytest.fixture
def restored() -> Iterator[None]:
    """Whatever a test does to this process's handlers is undone after it."""
    before = {signum: signal.getsignal(signum) for signum in HELD}
    yield
    for signum, handler in before.items():
        signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


def test_the_table_covers_every_signal_that_ends_a_process_by_default() -> None:
    # Linux: every catchable signal whose default action is to terminate or dump
    # core is either held (the daemon's table) or left alone on purpose.
    stop_or_ignore = {signal.SIGCHLD, signal.SIGCONT, signal.SIGURG, signal.SIGWINCH}
    stop_only = {signal.SIGTSTP, signal.SIGTTIN, signal.SIGTTOU}
    default_ends = set(signal.valid_signals()) - stop_or_ignore - stop_only
    default_ends -= {signal.SIGPIPE}  # Python ignores it from the start: EPIPE instead
    assert default_ends == set(HELD) | set(LEFT_ALONE)
    assert not set(HELD) & set(LEFT_ALONE)
    assert signal.SIGABRT in LEFT_ALONE  # systemd's watchdog must still be able to end a hang
    assert {signal.SIGALRM, signal.SIGSYS, signal.SIGSTKFLT, signal.SIGRTMAX} <= set(IGNORED)
    assert signal_name(signal.SIGRTMIN + 3) == "SIGRTMIN+3"
    assert signal_name(signal.SIGQUIT) == "SIGQUIT"


def test_held_signals_are_counted_then_handed_over_once_each_in_order(restored: None) -> None:
    held = SignalHold.hold()
    for signum in (signal.SIGHUP, signal.SIGALRM, signal.SIGHUP, signal.SIGTERM):
        signal.raise_signal(signum)  # each of them would end this process by default
    assert held.pending == {signal.SIGHUP: 2, signal.SIGALRM: 1, signal.SIGTERM: 1}
    assert held.stop_requested()
    got: list[int] = []
    held.deliver_to(got.append)
    assert got == [signal.SIGHUP, signal.SIGALRM, signal.SIGTERM]
    assert held.pending == {}
    signal.raise_signal(signal.SIGUSR2)  # later ones go straight to the target
    assert got[-1] == signal.SIGUSR2
    held.deliver_to(None)
    signal.raise_signal(signal.SIGQUIT)  # after the loop: counted, never fatal
    assert held.pending == {signal.SIGQUIT: 1}


def test_release_gives_the_handlers_back_and_raises_what_was_held(restored: None) -> None:
    seen: list[int] = []

    def mine(signum: int, frame: FrameType | None) -> None:
        seen.append(signum)

    signal.signal(signal.SIGUSR1, mine)
    held = SignalHold.hold()
    signal.raise_signal(signal.SIGUSR1)
    assert seen == []  # held, not handled
    held.release()
    assert seen == [signal.SIGUSR1]  # raised again, to the handler that was there
    assert signal.getsignal(signal.SIGUSR1) is mine
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    held.release()  # twice is harmless
    assert seen == [signal.SIGUSR1]


def test_the_daemon_done_ignores_its_signals_to_the_last_instant(restored: None) -> None:
    # The interpreter's exit gives Python handlers their default action back: a SIGHUP
    # then would end a clean stop by the signal (test_signals_e2e.py, end to end).
    done = SignalHold.hold()
    done.ignore_from_now()
    assert {signal.getsignal(signum) for signum in HELD} == {signal.SIG_IGN}
    signal.raise_signal(signal.SIGHUP)  # neither counted nor fatal
    assert done.pending == {}
    # A data command gave its handlers back: the exit is as if nothing had been held.
    for signum in HELD:
        signal.signal(signum, signal.SIG_DFL)
    command = SignalHold.hold()
    command.release()
    command.ignore_from_now()
    assert {signal.getsignal(signum) for signum in HELD} == {signal.SIG_DFL}


def test_a_data_command_keeps_ctrl_c_as_a_quiet_130(
    restored: None, capsys: pytest.CaptureFixture[str]
) -> None:
    held = SignalHold.hold()
    signal.raise_signal(signal.SIGINT)  # Ctrl-C while the command line was being read
    assert main(["decode", "50 53 00 48 00 EB"], held=held) == 130
    assert capsys.readouterr().out == ""
    # A command run on its own gets its handlers back (Ctrl-C: KeyboardInterrupt).
    assert main(["decode", "50 53 00 48 00 EB"]) == 0
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert signal.getsignal(signal.SIGHUP) == signal.SIG_DFL


def test_help_gives_the_handlers_back_too(restored: None) -> None:
    with pytest.raises(SystemExit):
        main(["--version"])
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


# Runs the real entry point (`python -m cc_daemon`) with an audit hook that looks at
# the handlers when the first heavy module is imported, and stops the process there.
_FIRST_HEAVY_IMPORT = """
import os, signal, sys
HEAVY = {"argparse", "asyncio", "pydantic", "structlog", "serial"}
def hook(event, args):
    if event == "import" and args[0] in HEAVY:
        from cc_daemon.ground.signals import HELD
        default = [s for s in HELD if signal.getsignal(s) in (signal.SIG_DFL, None)]
        print(args[0], len(HELD), sorted(int(s) for s in default), flush=True)
        os._exit(0)
sys.addaudithook(hook)
sys.argv = ["cc-daemon", "--config", "/nonexistent.toml"]
import runpy
runpy.run_module("cc_daemon", run_name="__main__", alter_sys=True)
"""


def test_every_signal_is_caught_before_anything_heavy_is_imported() -> None:
    out = subprocess.run(
        [sys.executable, "-c", _FIRST_HEAVY_IMPORT],
        capture_output=True,
        text=True,
        timeout=DEADLINE_S,
        cwd=REPO,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
        check=True,
    ).stdout.split(maxsplit=2)
    first, count, default = out
    assert first in {"argparse", "asyncio"}  # what the command line needs first
    assert int(count) == len(HELD)
    assert json.loads(default) == []  # not one of them left to its default action


class FakeDaemon:
    def __init__(self) -> None:
        self.shutdowns: list[bool] = []

    def request_shutdown(self, *, immediate: bool = False) -> None:
        self.shutdowns.append(immediate)

    def status_inputs(self) -> StatusInputs:
        return inputs(cast_id=3, phase="descending", depth=2.414, planned=5.0)


def inputs(*, cast_id: int | None, phase: str, depth: float, planned: float | None) -> StatusInputs:
    snap = DaemonStatus(
        link_up=True, phase=phase, probe_depth_m=depth, planned_depth_m=planned,
        cast_id=cast_id, frames_in=12, frames_out=10, corrupt_frames=1, casts_completed=2,
        casts_aborted=0, casts_skipped=0, winch_fault=None, port_losses=0, last_fix=None,
        winch=WinchStatus(depth, True, False, None),
    )  # fmt: skip

    def health() -> JournalHealth:
        return JournalHealth(
            path=None, writable=True, pending_rows=4, rows_written=120, write_errors=0,
            dropped_rows=0, last_error=None, writer_alive=True,
        )  # fmt: skip

    return StatusInputs(
        snapshot=snap, port="/dev/ttyAMA0", baudrate=9600, winch_backend="gpio",
        journal_health=health, monotonic=10.0, wall=1e9, uptime_s=10.0,
    )  # fmt: skip


def test_the_status_line_says_link_cast_winch_and_journal() -> None:
    line = status_line(inputs(cast_id=3, phase="descending", depth=2.414, planned=5.0))
    assert line == (
        "link up on /dev/ttyAMA0 (12 frames in, 10 out, 1 corrupt); "
        "cast 3 descending at 2.41 m of 5.00 m; "
        "winch gpio moving, not home, no fault; "
        "journal writable, 4 rows pending, 120 written, 0 write errors, 0 dropped"
    )
    idle = status_line(inputs(cast_id=None, phase="idle", depth=0.0, planned=None))
    assert "no cast, probe at 0.00 m" in idle


def test_the_table_on_the_loop(restored: None) -> None:
    daemon = FakeDaemon()
    reloads: list[int] = []
    table = DaemonSignals(daemon, lambda: reloads.append(1))
    held = SignalHold.hold()
    signal.raise_signal(signal.SIGHUP)  # before the loop: held

    async def serve() -> None:
        # Each signal's `handle` is queued on the loop (call_soon_threadsafe) before
        # `raise_signal` returns: one turn of the loop runs it, however slow the machine.
        async def handled() -> None:
            await asyncio.sleep(0)

        with table.delivered(held):
            await handled()
            assert reloads == [1]  # the held SIGHUP, once the loop runs
            for signum in (signal.SIGUSR1, signal.SIGUSR2, signal.SIGALRM, signal.SIGQUIT):
                signal.raise_signal(signum)
            await handled()
            assert daemon.shutdowns == [False]
            signal.raise_signal(signal.SIGTERM)  # a repeat changes nothing
            signal.raise_signal(signal.SIGINT)  # Ctrl-C after a SIGQUIT: not a second Ctrl-C
            await handled()
            assert daemon.shutdowns == [False]
            signal.raise_signal(signal.SIGINT)  # the second Ctrl-C: at once
            await handled()
            assert daemon.shutdowns == [False, True]

    with structlog.testing.capture_logs() as logs:
        asyncio.run(serve())
    assert daemon.shutdowns == [False, True]
    events: dict[str, dict[str, Any]] = {str(e["event"]): e for e in logs}
    assert "cast 3 descending at 2.41 m of 5.00 m" in events["status (SIGUSR1)"]["summary"]
    assert "SIGUSR2 received: it has no action (docs/signals.md)" in events
    assert events["signal ignored: it never stops the daemon"]["signal"] == "SIGALRM"
    assert events["signal received: bringing the probe home, then exiting"]["signal"] == "SIGQUIT"
    assert events["second Ctrl-C: stopping at once"]["signal"] == "SIGINT"
    signal.raise_signal(signal.SIGTERM)  # the loop is gone: counted, never fatal
    assert held.pending == {signal.SIGTERM: 1}


def test_from_another_thread_nothing_is_held(restored: None) -> None:
    before = signal.getsignal(signal.SIGTERM)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        held = pool.submit(SignalHold.hold).result()
    assert signal.getsignal(signal.SIGTERM) is before
    held.release()  # nothing to give back, nothing raised
    assert held.pending == {}


def test_ctrl_c_during_help_is_no_traceback(restored: None) -> None:
    held = SignalHold.hold()
    signal.raise_signal(signal.SIGINT)
    with pytest.raises(SystemExit):  # --version's own exit, not a KeyboardInterrupt
        main(["--version"], held=held)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_daemon_run_ending_early_in_process_leaves_the_handlers_as_found(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    for name in [n for n in os.environ if n.startswith("CC_DAEMON_")]:
        monkeypatch.delenv(name)
    before = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGINT)}
    # The default simulated winch is refused (exit 2) after the signals were held.
    assert main(["--port", str(tmp_path / "tty"), "--db", str(tmp_path / "j.db")]) == 2
    assert {signum: signal.getsignal(signum) for signum in before} == before
