"""The daemon subprocess and its journal: killed mid-cast, and a store it cannot write.

The journal's own tests drive `Journal` directly; these check the promises
through the real daemon: what went over the link is in the file, a SIGKILL
loses nothing older than a second, and a store that the daemon can no longer write
never stops a cast or a reply.
"""

from __future__ import annotations

import contextlib
import signal
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from cc_daemon.core.protocol import Ack, DepthReport, Finished, ProbePosition, ProbePositionRequest
from tests.daemonkit import DaemonProcess, collect_until, station
from tests.test_journal_faults import read_only
from tests.waitkit import until

pytestmark = pytest.mark.slow
MakeDaemon = Callable[..., DaemonProcess]

# "Nothing older than a second is lost": a row is durable about a millisecond after
# the call (benchmarks/journal.py); checked here with a margin no load reaches.
DURABLE_AFTER_S = 2.5


async def test_sigkill_mid_cast_keeps_every_sample_older_than_a_second(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon({"cast": {"target_depth_m": 8.0}})  # 8 s down at 1 m/s
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack)
    reports: list[tuple[float, int]] = []  # (received at, depth): sent no later than that
    while sum(at < time.monotonic() - DURABLE_AFTER_S for at, _ in reports) < 3:
        got = await daemon.expect(DepthReport)
        assert got is not None and isinstance(got.message, DepthReport)
        reports.append((got.time, got.message.depth_mm))
    assert daemon.proc is not None
    killed_at = time.monotonic()
    daemon.proc.kill()
    daemon.proc.wait(5)
    older = [depth for at, depth in reports if at < killed_at - DURABLE_AFTER_S]
    assert len(older) >= 3
    with sqlite3.connect(daemon.db) as db:
        stored = {round(d * 1000) for (d,) in db.execute("SELECT depth_m FROM samples")}
        (outcome,) = db.execute("SELECT outcome FROM casts WHERE id = 1").fetchone()
    assert set(older) <= stored
    assert outcome is None  # nobody got to end it

    # The next start marks it unfinished, says so, and serves as usual.
    daemon.start()
    await daemon.wait_answering()
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    with sqlite3.connect(daemon.db) as db:
        assert db.execute("SELECT outcome FROM casts WHERE id = 1").fetchone() == ("unfinished",)
    warned = [e for e in daemon.log_events() if e.get("level") == "warning"]
    assert any("unfinished" in str(e.get("event")) for e in warned)


def _started(journal: Path) -> bool:
    if not (journal.exists() and journal.with_name(journal.name + "-wal").exists()):
        return False
    try:
        with sqlite3.connect(f"file:{journal}?mode=ro", uri=True) as db:
            kinds = db.execute("SELECT kind FROM events").fetchall()
    except sqlite3.OperationalError:
        return False
    return ("daemon_started",) in kinds


def _completed_cast(journal: Path) -> list[tuple[object, ...]] | None:
    if not journal.exists():
        return None
    try:
        with sqlite3.connect(journal) as db:
            rows = db.execute(
                "SELECT c.outcome, COUNT(s.id) FROM casts c JOIN samples s "
                "ON s.cast_id = c.id GROUP BY c.id"
            ).fetchall()
    except sqlite3.OperationalError:
        return None
    return rows if rows and rows[0][0] == "completed" else None


async def test_a_store_that_turns_read_only_stops_neither_casts_nor_replies(
    make_daemon: MakeDaemon, tmp_path: Path
) -> None:
    # (A store that cannot be opened at start is a configuration error: exit 2,
    # see tests/test_preflight.py. One that fails mid-survey is survived.)
    store = tmp_path / "store"
    store.mkdir()
    journal = store / "journal.db"
    daemon = make_daemon({"store": {"path": str(journal)}})
    port = await daemon.start_and_connect()
    # The first rows are in; the WAL exists.
    await until(lambda: _started(journal), what="the daemon's start journaled")
    with contextlib.ExitStack() as undo:
        for path in (store, journal, store / "journal.db-wal"):
            undo.enter_context(read_only(path))
        await port.send(station())
        await daemon.expect(Ack)
        await collect_until(port, lambda m: isinstance(m, DepthReport) and m.depth_mm > 0)
        await port.send(ProbePositionRequest(3))
        reply = await daemon.expect(ProbePosition)
        assert reply is not None and reply.message.depth_mm > 0
        assert await daemon.expect(Finished) is not None  # the cast ran to the end
        with sqlite3.connect(f"file:{journal}?mode=ro", uri=True) as db:
            assert db.execute("SELECT COUNT(*) FROM casts").fetchone() == (0,)
    # The journal kept the rows and writes them once it can. The backlog goes in
    # over a few passes (spilled rows replayed first): wait for the cast's end, not
    # just its start.
    rows = await until(lambda: _completed_cast(journal), what="the cast's rows written")
    assert rows[0][0] == "completed" and int(rows[0][1]) >= 8  # type: ignore[call-overload]
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
