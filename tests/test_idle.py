"""Idle means asleep (issue 22, docs/performance.md): no tick when nothing is due.

The line watch sleeps until its machines' own deadlines (`LineWatch.next_deadline`),
the housekeeping until its own (`Housekeeping.next_deadline`), and the journal's
writer thread until a row arrives. The whole daemon's wake-ups are counted end to
end in tests/test_lean_daemon.py.
"""

from __future__ import annotations

import io
import math
import socket
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.config import load_settings
from cc_daemon.core.cast.jog import Stick
from cc_daemon.core.cast.lost_start import LostStartWatch
from cc_daemon.core.protocol import Finished, Telemetry
from cc_daemon.core.winch.status import WinchStatus
from cc_daemon.daemon.housekeeping import CORRUPT_SUMMARY_S, Housekeeping
from cc_daemon.daemon.line_watch import TICK_S, LineWatch
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.ground.clock import SystemClock
from cc_daemon.ground.logsetup import configure_logging, reset_logging
from cc_daemon.store import Journal

T = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)


def _watch(status: WinchStatus | None = None) -> tuple[LineWatch, list[bytes]]:
    settings = load_settings(None, {"store": {"path": "unused.db"}})
    written: list[bytes] = []
    home = status or WinchStatus(depth_m=0.0, at_home=True, moving=False, fault=None)

    def write(frame: bytes) -> bool:
        written.append(frame)
        return True

    def ignore(*_: Any, **__: Any) -> None:
        return None

    watch = LineWatch(
        settings,
        write=write,
        move_winch=ignore,
        stop_winch=ignore,
        winch_status=lambda: home,
        journal_event=ignore,
        notify=ignore,
    )
    return watch, written


def test_nothing_is_due_when_nothing_happens():
    watch, _ = _watch()
    assert watch.next_deadline(10.0, cast_running=False) is None
    watch.heard(T, 10.0)
    assert watch.next_deadline(11.0, cast_running=False) is None


def test_an_rf_repeat_is_due_at_its_own_time_and_set_wakes_the_watch():
    watch, written = _watch()
    watch.changed.clear()
    watch.finished_sent(Finished(1, 0), 100.0)
    assert watch.changed.is_set()  # the sleeping watch recomputes at once
    after = watch.rf.after_s
    assert watch.next_deadline(100.0, cast_running=False) == 100.0 + after
    watch.tick(100.0 + after, cast_running=False)
    assert len(written) == 1  # sent again exactly at the deadline
    watch.heard(T, 100.0 + after + 0.5)
    assert watch.next_deadline(101.0 + after, cast_running=False) is None


def test_the_lost_m_deadline_is_the_first_moment_the_watch_suspects():
    watch, _ = _watch()
    watch.heard(T, 50.0)
    watch.changed.clear()
    watch.corrupt(50.0)
    assert watch.changed.is_set()
    deadline = watch.next_deadline(50.5, cast_running=False)
    assert deadline is not None and 53.0 < deadline < 53.0 + 1e-9
    assert watch.lost.check(53.0, cast_running=False) is None  # not yet: more than 3 s
    assert watch.lost.check(deadline, cast_running=False) is not None
    assert watch.next_deadline(deadline, cast_running=False) is None  # said once
    assert watch.next_deadline(51.0, cast_running=True) is None


def test_a_jog_is_watched_every_tick_while_it_runs():
    down = WinchStatus(depth_m=2.0, at_home=False, moving=True, fault=None)
    watch, _ = _watch(down)
    watch.changed.clear()
    watch.stick(Stick.UP, 20.0)
    assert watch.jog.active and watch.changed.is_set()
    assert watch.next_deadline(20.0, cast_running=False) == 20.0 + TICK_S
    watch.stop_jog(20.05, "test")
    assert watch.next_deadline(20.05, cast_running=False) is None


def test_lost_start_watch_has_no_deadline_without_a_corrupt_frame():
    watch = LostStartWatch(silence_s=3.0)
    assert watch.next_deadline(cast_running=False) is None
    watch.heard(0.0)
    assert watch.next_deadline(cast_running=False) is None
    watch.corrupt(0.0)
    assert watch.next_deadline(cast_running=False) == math.nextafter(3.0, math.inf)


def _voluntary_switches(native_id: int) -> int:
    status = Path(f"/proc/self/task/{native_id}/status").read_text()
    return int(status.split("voluntary_ctxt_switches:")[1].split()[0])


def _poll(check: Callable[[], bool], what: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, f"not within {timeout} s: {what}"
        time.sleep(0.02)


def _count(db: Path, table: str) -> int:
    with sqlite3.connect(db) as conn:
        return int(conn.execute(f"SELECT count(*) FROM {table}").fetchone()[0])


def _settled(native_id: int, quiet_s: float = 0.3) -> bool:
    """The thread did not wake for `quiet_s` (done with what it was doing, asleep)."""
    before = _voluntary_switches(native_id)
    time.sleep(quiet_s)
    return _voluntary_switches(native_id) == before


def test_the_journal_writer_sleeps_until_a_row_arrives(tmp_path):
    db = tmp_path / "j.db"
    journal = Journal(db)
    journal.open()
    try:
        journal.record_event("hello")
        _poll(lambda: _count(db, "events") > 0, "the event written (an event wakes the writer)")
        writer = next(t for t in threading.enumerate() if t.name == "cc-daemon-journal")
        assert writer.native_id is not None
        native_id = writer.native_id
        # Done with the commit (its fsync is a sleep of its own), asleep. A writer that
        # ticked once a second is still caught: it settles between ticks, then ticks
        # twice in the 2.5 s below.
        _poll(lambda: _settled(native_id), "the writer asleep after its commit", timeout=10.0)
        before = _voluntary_switches(native_id)
        time.sleep(2.5)
        assert _voluntary_switches(native_id) - before == 0  # was one a second
        journal.record_fix(T)  # a fix into an empty buffer wakes it too (else: never written)
        _poll(lambda: _count(db, "fixes") > 0, "the fix written")
    finally:
        journal.close()


@pytest.fixture
def _fresh_log() -> Iterator[None]:
    """A log with no count held back by an earlier test in this process."""
    configure_logging("json", "info", io.StringIO())
    yield
    reset_logging()


def _housekeeping(
    notifier: SystemdNotifier | None = None,
) -> tuple[Housekeeping, list[tuple[str, dict[str, Any]]], list[int]]:
    events: list[tuple[str, dict[str, Any]]] = []
    corrupt = [0]
    keeper = Housekeeping(
        clock=SystemClock(),
        notifier=notifier or SystemdNotifier(None),
        port=lambda: "/dev/ttyS0",
        corrupt_frames=lambda: corrupt[0],
        journal_event=lambda kind, **detail: events.append((kind, detail)),
    )
    return keeper, events, corrupt


@pytest.mark.usefixtures("_fresh_log")
def test_housekeeping_has_nothing_due_when_nothing_happens():
    keeper, events, _ = _housekeeping()
    keeper.tick(10.0)
    assert keeper.next_deadline(10.0) is None  # was a tick every second
    keeper.port_opened(10.0)
    assert keeper.next_deadline(10.0) == 15.0  # a silent port is said after 5 s
    keeper.heard()
    assert keeper.next_deadline(11.0) is None
    assert events == []


@pytest.mark.usefixtures("_fresh_log")
def test_corrupt_frames_are_counted_once_a_while_after_the_first():
    keeper, events, corrupt = _housekeeping()
    keeper.tick(100.0)
    keeper.changed.clear()
    corrupt[0] = 1
    keeper.corrupt(100.0)
    assert keeper.changed.is_set()  # the sleeping duty recomputes at once
    keeper.changed.clear()
    corrupt[0] = 3
    keeper.corrupt(101.0)
    keeper.corrupt(102.0)
    assert not keeper.changed.is_set()  # the deadline stands: no news
    due = keeper.next_deadline(102.0)
    assert due == 100.0 + CORRUPT_SUMMARY_S
    keeper.tick(due - 0.5)
    assert events == []
    keeper.tick(due)
    assert events == [("corrupt_frames", {"new": 3, "total": 3})]
    assert keeper.next_deadline(due) is None


@pytest.mark.usefixtures("_fresh_log")
def test_the_watchdog_is_pinged_at_half_of_watchdog_sec(tmp_path):
    path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(path))
        server.setblocking(False)
        notifier = SystemdNotifier(str(path), watchdog=True, watchdog_s=60.0)
        keeper, _, _ = _housekeeping(notifier)
        try:
            keeper.tick(0.0)
            assert keeper.next_deadline(0.0) == 30.0
            keeper.tick(29.0)
            with pytest.raises(BlockingIOError):
                server.recv(64)  # not yet
            keeper.tick(30.0)
            assert server.recv(64) == b"WATCHDOG=1"
            assert keeper.next_deadline(30.0) == 60.0
        finally:
            notifier.close()


@pytest.mark.parametrize("order", ["big", "little"])
def test_fixes_read_together_are_heard_as_each_alone(order: str):
    # The daemon hands a run of T frames read at once to `heard_fixes`: the byte-order
    # votes, the decision and the time returned must be those of hearing each alone.
    one_by_one, _ = _watch()
    together, _ = _watch()
    stamp = 300
    for read in range(12):  # a read every 1.1 s, a run of 1 to 4 T frames in each
        now = 50.0 + read * 1.1
        stamp += 1 if read % 5 else 2  # the firmware's whole-second clock
        raw = stamp if order == "big" else (stamp & 0xFF) << 8 | stamp >> 8
        run = [T._replace(timestamp_s=raw) for _ in range(1 + read % 4)]
        alone = [one_by_one.heard(fix, now) for fix in run][-1]
        assert together.heard_fixes(run, now) == alone
        assert (together.order.order, together.order.decided) == (
            one_by_one.order.order,
            one_by_one.order.decided,
        )
    assert together.order.decided and together.order.order == order
