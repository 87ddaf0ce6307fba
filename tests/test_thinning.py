"""Telemetry journaled at most `store.telemetry_rate_hz`: the latest fix of each interval."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cc_daemon.core.protocol import Parser, Sender, Telemetry, TelemetryRun, encode
from cc_daemon.store import Journal
from cc_daemon.store.synthetic import FakeClock
from cc_daemon.store.thinning import FixThinner, buffer_rows
from tests.test_journal import query, wait_for

FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)


def test_the_latest_fix_of_each_interval_is_kept_and_the_rest_counted() -> None:
    thinner = FixThinner(2.0, report_every_s=60.0)
    out = []
    # Ten fixes in each half second from t=100.0 to t=101.9: 0.05 s apart.
    for i in range(40):
        mono = 100.0 + i * 0.05
        ready = thinner.offer(("fix", i), mono)
        if ready is not None:
            out.append(ready[1])
    assert out == [9, 19, 29]  # each interval's last, handed on when the next one starts
    assert thinner.due(101.95) is None  # its interval is not over: it may still be replaced
    assert thinner.due(102.0) == ("fix", 39)
    assert thinner.thinned == 36
    assert thinner.report(102.0) == 0  # the first report is a minute after the first call
    assert thinner.report(162.0) == 36
    assert (thinner.thinned, thinner.report(300.0)) == (0, 0)


def test_slow_telemetry_is_all_kept() -> None:
    thinner = FixThinner(2.0)
    kept = [r for i in range(10) if (r := thinner.offer(("fix", i), 100.0 + i * 1.1))]
    assert [r[1] for r in kept] == list(range(9))
    assert thinner.take() == ("fix", 9)
    assert thinner.thinned == 0


def test_a_rate_must_be_a_positive_number() -> None:
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="telemetry rate"):
            FixThinner(bad)


def test_the_buffer_is_sized_from_the_rate() -> None:
    assert buffer_rows(2.0) == 26_200
    assert buffer_rows(10.0) == 55_000
    # Sized from the rate unless told otherwise; unthinned, the old default.
    assert Journal(Path("x.db"), telemetry_rate_hz=2.0)._max_rows == 26_200
    assert Journal(Path("x.db"))._max_rows == 100_000


def test_a_flood_of_fixes_reaches_the_file_at_the_rate(tmp_path: Path) -> None:
    clock = FakeClock()
    db = tmp_path / "j.db"
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall, telemetry_rate_hz=2.0)
    journal.open()
    try:
        # 100 s of a flood: 1000 fixes a second (timestamps count them).
        for n in range(100_000):
            journal.record_fix(FIX._replace(timestamp_s=n % 65536))
            clock.advance(0.001)
    finally:
        journal.close()
    rows = query(db, "SELECT mono_s, ap_timestamp_s FROM fixes ORDER BY id")
    assert 199 <= len(rows) <= 201  # 2 Hz for 100 s
    # Each kept fix is the last of its half second (the clock's steps are floats:
    # the boundary falls either side of the 500th), with its own arrival time.
    first_mono, first_ts = rows[0]
    assert first_ts in (499, 500) and first_mono == pytest.approx(1000.0 + first_ts / 1000)
    details = [
        json.loads(d)
        for (d,) in query(db, "SELECT detail_json FROM events WHERE kind = 'telemetry_thinned'")
    ]
    assert len(details) >= 2  # a minute apart, and the rest at close
    assert all(d["rate_hz"] == 2.0 for d in details)
    # Every fix is kept or counted: none is lost silently.
    assert sum(d["dropped"] for d in details) + len(rows) == 100_000


def test_a_held_fix_reaches_the_file_when_telemetry_stops(tmp_path: Path) -> None:
    clock = FakeClock()
    db = tmp_path / "j.db"
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall, telemetry_rate_hz=2.0)
    journal.open()
    try:
        journal.record_fix(FIX)
        clock.advance(0.6)  # its interval is over; the writer's next pass (<= 1 s) releases it
        wait_for(lambda: query(db, "SELECT count(*) FROM fixes") == [(1,)], timeout=30)
    finally:
        journal.close()


def test_the_rate_changes_on_reload(tmp_path: Path) -> None:
    clock = FakeClock()
    db = tmp_path / "j.db"
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall, telemetry_rate_hz=2.0)
    journal.open()
    try:
        journal.set_telemetry_rate(0.5)
        assert journal._max_rows == buffer_rows(0.5)
        for n in range(20):  # 10 s at 2 fixes a second, thinned to one every 2 s
            journal.record_fix(FIX._replace(timestamp_s=n))
            clock.advance(0.5)
    finally:
        journal.close()
    assert query(db, "SELECT count(*) FROM fixes") == [(5,)]


def test_fixes_read_together_are_one_instant_the_last_kept(tmp_path: Path) -> None:
    # A flood's path (the daemon hands each run of P-T read at once as one):
    # as if each had been recorded at that instant, and no row made for the others.
    thinner = FixThinner(2.0)
    assert thinner.offer(("fix", 0), 100.0) is None
    assert thinner.offer(("fix", 9), 100.1, replaced=8) is None  # 1..8 never offered
    assert thinner.thinned == 9  # 0 replaced by 9, and the 8 before it
    assert thinner.offer(("fix", 10), 100.6, replaced=0) == ("fix", 9)

    clock = FakeClock()
    db = tmp_path / "j.db"
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall, telemetry_rate_hz=2.0)
    journal.open()
    try:
        for run in range(4):  # four reads half a second apart, 50 fixes each
            fixes = [FIX._replace(timestamp_s=run * 50 + n) for n in range(50)]
            journal.record_fixes(fixes, decode=lambda raw: raw + 1000, ap_time_order="big")
            clock.advance(0.5)
    finally:
        journal.close()
    rows = query(db, "SELECT ap_timestamp_s, ap_time_s FROM fixes ORDER BY id")
    assert rows == [(49, 1049), (99, 1099), (149, 1149), (199, 1199)]  # each read's last
    dropped = query(db, "SELECT detail_json FROM events WHERE kind = 'telemetry_thinned'")
    assert sum(json.loads(d)["dropped"] for (d,) in dropped) == 4 * 49  # none lost silently


def parsed_run(fixes: list[Telemetry]) -> TelemetryRun:
    [run] = Parser(Sender.AUTOPILOT).events_in_runs(b"".join(map(encode, fixes)))
    assert isinstance(run, TelemetryRun)
    return run


def test_a_parsed_run_is_journaled_as_the_fixes_it_holds(tmp_path: Path) -> None:
    # The daemon hands the journal a run as the parser made it: only its last
    # fix decoded up front; a thinned journal needs no other, an unthinned one
    # decodes every fix of it.
    fixes = [FIX._replace(timestamp_s=n, sonar_distance_mm=n) for n in range(30)]
    clock = FakeClock()
    thinned, every = tmp_path / "thinned.db", tmp_path / "every.db"
    journals = [
        Journal(thinned, monotonic=clock.monotonic, wall=clock.wall, telemetry_rate_hz=2.0),
        Journal(every, monotonic=clock.monotonic, wall=clock.wall),
    ]
    for journal in journals:
        journal.open()
        try:
            journal.record_fixes(parsed_run(fixes), decode=lambda raw: raw, ap_time_order="big")
        finally:
            journal.close()
    assert query(thinned, "SELECT ap_timestamp_s, sonar_distance_mm FROM fixes") == [(29, 29)]
    dropped = query(thinned, "SELECT detail_json FROM events WHERE kind = 'telemetry_thinned'")
    assert sum(json.loads(d)["dropped"] for (d,) in dropped) == 29
    assert query(every, "SELECT ap_timestamp_s FROM fixes ORDER BY id") == [(n,) for n in range(30)]


def test_fixes_read_together_unthinned_are_all_kept(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    journal = Journal(db)  # a library's journal: no rate, every fix kept
    journal.open()
    try:
        journal.record_fixes([FIX._replace(timestamp_s=n) for n in range(3)], decode=lambda r: -r)
    finally:
        journal.close()
    assert query(db, "SELECT ap_timestamp_s, ap_time_s FROM fixes ORDER BY id") == [
        (0, 0),
        (1, -1),
        (2, -2),
    ]
