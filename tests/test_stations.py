"""One naming and one count of stations everywhere (issue 29): S1, S2... in the order
asked, or the simulator's mission names when the journal holds its plan; a planned
station whose M was lost still counts; the surveys table and the verdict agree."""

from __future__ import annotations

from pathlib import Path

import pytest

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.stations import (
    PLAN_EVENT,
    Place,
    PlannedStation,
    counts,
    distance_m,
    names,
    plan_detail,
    read_plan,
    stations,
)
from cc_daemon.store.synthetic import FakeClock

LAT, LON = 40.4506308, -3.7260579
STEP = 0.002  # degrees of latitude between stations: about 222 m


def place(cast_id: int, k: float, outcome: str | None = "completed") -> Place:
    return Place(cast_id, LAT + k * STEP, LON, outcome)


def test_without_a_plan_stations_are_named_in_the_order_first_asked() -> None:
    casts = [place(7, 0), place(8, 1, "skipped-shallow"), place(9, 2, "aborted"), place(10, 0)]
    found = stations(casts, None)
    assert [s.name for s in found] == ["S1", "S2", "S3"]
    assert found[0].cast_ids == (7, 10)  # asked again at S1 after its re-arm window
    assert names(found) == {7: "S1", 8: "S2", 9: "S3", 10: "S1"}
    assert [s.castable for s in found] == [True, False, True]  # S2 only ever too shallow
    assert counts(found) == (3, 2, 1)


def test_a_plan_names_the_casts_and_counts_a_station_never_asked() -> None:
    plan = [PlannedStation(f"S{n + 1}", LAT + n * STEP, LON, castable=n != 2) for n in range(3)]
    # The seed-2 run: S2's M lost (no cast there), S3 a shoal never reached.
    found = stations([place(1, 0)], plan)
    assert [(s.name, s.cast_ids, s.measured) for s in found] == [
        ("S1", (1,), True),
        ("S2", (), False),
        ("S3", (), False),
    ]
    assert counts(found) == (3, 2, 1)  # "1 of 2 castable stations measured", 3 stations
    # A cast nowhere near the plan is a station too, named after the plan's.
    extra = stations([place(1, 0), Place(2, LAT - 0.01, LON, "completed")], plan)
    assert [s.name for s in extra] == ["S1", "S2", "S3", "S4"] and not extra[3].planned


def test_a_plan_from_a_damaged_or_foreign_journal_is_not_believed() -> None:
    good = plan_detail([("S1", LAT, LON, True), ("S2", LAT + STEP, LON, None)])
    assert read_plan(good) == [
        PlannedStation("S1", LAT, LON, True),
        PlannedStation("S2", pytest.approx(LAT + STEP), LON, None),
    ]
    for bad in (
        None,
        {},
        {"stations": []},
        {"stations": "S1"},
        {"stations": [{"name": "S1", "lat_deg": 91.0, "lon_deg": 0.0}]},
        {"stations": [{"name": "S1", "lat_deg": float("nan"), "lon_deg": 0.0}]},
        {"stations": [{"name": "S1", "lat_deg": True, "lon_deg": 0.0}]},
        {"stations": [{"name": "\x1b[2J", "lat_deg": 1.0, "lon_deg": 0.0}]},
        {"stations": [{"name": "x" * 41, "lat_deg": 1.0, "lon_deg": 0.0}]},
        {"stations": [["S1", 1.0, 0.0]]},
    ):
        assert read_plan(bad) is None, bad


def test_distances_are_metres() -> None:
    assert distance_m(LAT, LON, LAT + STEP, LON) == pytest.approx(222.4, abs=0.5)
    assert distance_m(LAT, LON, LAT, LON + 0.001) == pytest.approx(84.7, abs=0.5)


def _journal(db: Path, clock: FakeClock, *, plan: bool) -> None:
    journal = Journal(
        db,
        monotonic=clock.monotonic,
        wall=clock.wall,
        winch_backend="sim" if plan else "gpio",
        simulated=plan,  # only a simulation records a plan, and only its plan is read
    )
    journal.open()
    for _ in range(5):  # the daemon's own first events
        journal.record_event("port_opened", port="/dev/pts/7")
    if plan:
        journal.record_event(
            PLAN_EVENT,
            **plan_detail([(f"S{n + 1}", LAT + n * STEP, LON, n != 2) for n in range(3)]),
        )
    lat_e7, lon_e7 = round(LAT * 1e7), round(LON * 1e7)
    journal.record_fix(Telemetry(1, lon_e7, lat_e7, 0, 4000, 90))
    cast = journal.start_cast(
        StartMeasuring(2, lon_e7, lat_e7, 0, 4000, 90),
        planned_depth_m=3.5,
        mode="continuous",
        plan={},
    )
    clock.advance(5.0)
    journal.record_sample(cast, 1.0, "descending")
    journal.end_cast(cast, outcome="completed", reached_depth_m=3.5)
    journal.close()
    clock.advance(600.0)


def test_the_reader_counts_and_names_each_survey_by_its_own_plan(tmp_path: Path) -> None:
    db, clock = tmp_path / "j.db", FakeClock()
    _journal(db, clock, plan=True)  # survey 1: the simulator's plan, S2's M lost
    _journal(db, clock, plan=False)  # survey 2: a real survey, no plan
    with JournalReader(db) as reader:
        first, second = reader.surveys()
        assert (first.stations, first.castable, first.measured) == (3, 2, 1)
        assert (second.stations, second.castable, second.measured) == (1, 1, 1)
        reader.select_survey(first.id)
        assert [s.name for s in reader.stations()] == ["S1", "S2", "S3"]
        reader.select_survey(second.id)
        [only] = reader.stations()
        assert only.name == "S1" and only.cast_ids == (2,) and not only.planned


def test_a_plan_is_found_among_a_long_journals_first_events_of_its_session(
    tmp_path: Path,
) -> None:
    db, clock = tmp_path / "j.db", FakeClock()
    for _ in range(3):
        _journal(db, clock, plan=True)
        journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall, simulated=True)
        journal.open()  # a run with a thousand events and no plan between the others
        for n in range(1000):
            journal.record_event("sonde_reading_failed", n=n)
        journal.close()
    with JournalReader(db) as reader:
        counted = [(s.stations, s.castable, s.measured) for s in reader.surveys()]
    assert counted == [(3, 2, 1)] * 3  # a run that recorded only events is no survey
