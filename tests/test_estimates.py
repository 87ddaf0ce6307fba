"""Plots and exports never overstate (issue 29): a depth the winch could only estimate is
drawn as an estimate and flagged in the CSV with its range; a title says what its
trace shows; surveys are never joined by a line; labels cover no station."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.exportfiles import samples_csv
from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.export import estimates
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock

LAT_E7, LON_E7 = 404506308, -37260579
RANGE = {"depth_low_m": 0.0, "depth_high_m": 2.686, "depth_by": "dead reckoning"}


def _station(k: int) -> StartMeasuring:
    return StartMeasuring(k, LON_E7, LAT_E7 + 20000 * k, 0, 3200, 95)


def _cast(journal: Journal, clock: FakeClock, k: int, planned: float) -> int:
    return journal.start_cast(_station(k), planned_depth_m=planned, mode="continuous", plan={})


def _survey(db: Path, clock: FakeClock) -> dict[str, int]:
    """Three casts as the simulator's faults leave them: an encoder that died on the way
    up, a stall between two samples, a station refused with the probe jammed."""
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall, winch_backend="gpio-mock")
    journal.open()
    for k in range(3):
        journal.record_fix(Telemetry(k, LON_E7, LAT_E7 + 20000 * k, 0, 3200, 95))
        clock.advance(1.0)
    dead = _cast(journal, clock, 0, 2.64)
    for depth, phase in [(0.0, "descending"), (1.3, "descending"), (2.686, "dwelling")]:
        journal.record_sample(dead, depth, phase)
        clock.advance(1.0)
    journal.record_sample(dead, 2.686, "ascending")  # the count frozen: not yet known
    clock.advance(0.5)
    journal.record_event("winch_fault", fault="encoder dead", line_m=0.244, **RANGE)
    journal.record_event("cast_aborted", cast_id=dead, depth_m=0.244, reason="encoder dead")
    clock.advance(0.5)
    for _ in range(4):
        journal.record_sample(dead, 0.244, "stranded")
        clock.advance(1.0)
    journal.end_cast(dead, outcome="unfinished", reached_depth_m=2.686)
    stall = _cast(journal, clock, 1, 2.68)
    journal.record_sample(stall, 0.0, "descending")
    clock.advance(0.8)
    journal.record_event("cast_aborted", cast_id=stall, depth_m=1.0, reason="stall at 1.00 m")
    clock.advance(0.2)
    journal.record_sample(stall, 0.75, "aborting")
    clock.advance(0.6)
    journal.record_sample(stall, 0.0, "aborting")
    journal.end_cast(stall, outcome="aborted", reached_depth_m=1.0, reason="stall at 1.00 m")
    refused = _cast(journal, clock, 2, 0.0)
    for _ in range(3):
        journal.record_sample(refused, 0.5, "stranded")
        clock.advance(1.0)
    journal.end_cast(refused, outcome="unfinished", reached_depth_m=0.5)
    journal.close()
    return {"dead": dead, "stall": stall, "refused": refused}


@pytest.fixture
def survey(tmp_path: Path) -> tuple[Path, dict[str, int]]:
    db = tmp_path / "j.db"
    return db, _survey(db, FakeClock())


def test_the_csv_flags_each_estimated_depth_with_its_range(
    survey: tuple[Path, dict[str, int]],
) -> None:
    db, ids = survey
    out = io.StringIO(newline="")
    with JournalReader(db) as reader:
        casts = reader.casts()
        samples_csv(reader, casts, reader.samples(), out)
    rows = list(csv.DictReader(line for line in out.getvalue().splitlines() if line[0] != "#"))
    dead = [r for r in rows if r["cast_id"] == str(ids["dead"])]
    measured = [(r["depth_m"], r["depth_low_m"], r["depth_high_m"]) for r in dead[:4]]
    assert measured == [
        ("0.000", "", ""), ("1.300", "", ""), ("2.686", "", ""), ("2.686", "", "")
    ]  # fmt: skip
    assert [(r["depth_m"], r["depth_low_m"], r["depth_high_m"]) for r in dead[4:]] == [
        ("0.244", "0.000", "2.686")
    ] * 4
    assert {r["station"] for r in rows} == {"S1", "S2", "S3"}
    assert all(r["depth_low_m"] == "" for r in rows if r["cast_id"] != str(ids["dead"]))


def test_the_trace_holds_the_winchs_depth_between_two_samples(
    survey: tuple[Path, dict[str, int]],
) -> None:
    db, ids = survey
    with JournalReader(db) as reader:
        [cast] = reader.casts(cast_id=ids["stall"])
        points = estimates.trace(cast, reader.samples(cast_id=cast.id), reader.events(), None)
    assert [(p.depth_m, p.sampled) for p in points] == [
        (0.0, True), (1.0, False), (0.75, True), (0.0, True)
    ]  # fmt: skip
    assert max(p.depth_m for p in points) == cast.reached_depth_m


pytest.importorskip("matplotlib")


def _figure(db: Path, cast_id: int) -> Any:
    from cc_daemon.export.plot import cast_figure

    with JournalReader(db) as reader:
        [cast] = reader.casts(cast_id=cast_id)
        return cast_figure(cast, reader.samples(cast_id=cast_id), reader.events())


def _labels(fig: Any) -> list[str]:
    [legend] = fig.legends
    return [t.get_text() for t in legend.get_texts()]


def test_an_estimated_depth_is_drawn_dashed_over_its_range(
    survey: tuple[Path, dict[str, int]],
) -> None:
    db, ids = survey
    fig = _figure(db, ids["dead"])
    [ax] = fig.axes
    lines = {line.get_label(): line for line in ax.get_lines()}
    measured = lines["probe depth, measured by the winch"]
    guess = lines["best estimate (dead reckoning; not measured)"]
    assert measured.get_linestyle() == "-" and guess.get_linestyle() == "--"
    assert max(measured.get_ydata()) == pytest.approx(2.686)
    assert next(iter(guess.get_ydata())) == pytest.approx(2.686)  # the jump up is a guess too
    assert list(guess.get_ydata())[-1] == pytest.approx(0.244)
    assert "where the probe may be (0.00 to 2.69 m)" in _labels(fig)
    title = ax.get_title()
    assert "measured down to 2.69 m" in title and "then estimated: 0.00 to 2.69 m" in title


def test_a_title_gives_the_depth_its_trace_reaches(survey: tuple[Path, dict[str, int]]) -> None:
    db, ids = survey
    fig = _figure(db, ids["stall"])
    [ax] = fig.axes
    assert "reached 1.00 m" in ax.get_title()
    trace = [line for line in ax.get_lines() if line.get_label().startswith("probe depth")]
    drawn = [y for line in trace for y in line.get_ydata()]
    drawn += [float(y) for c in ax.collections for _, y in c.get_offsets()]
    assert max(drawn) == pytest.approx(1.0)  # the trace peaks where the title says
    assert "the winch's depth at the fault (between samples)" in _labels(fig)
    # A refused station has no plan: no "planned depth" on the axis where none can see it.
    assert "planned depth" in _labels(fig)
    assert "planned depth" not in _labels(_figure(db, ids["refused"]))


def test_survey_all_never_joins_two_surveys_and_labels_cover_no_station(tmp_path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from cc_daemon.export.plot import survey_figure

    db, clock = tmp_path / "j.db", FakeClock()
    _survey(db, clock)
    clock.advance(3600.0)
    _survey(db, clock)
    with JournalReader(db) as reader:
        reader.select_survey("all")
        casts, fixes, stations = reader.casts(), reader.fixes(), reader.stations()
    fig = survey_figure(casts, fixes, stations)
    ax = fig.axes[0]
    tracks = [line for line in ax.get_lines() if len(line.get_xdata()) > 1]
    assert len(tracks) == 2  # one line per survey, none from one to the other
    assert all(len(line.get_xdata()) == 3 for line in tracks)
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    labels = [t for t in ax.texts if t.get_text()]
    assert sorted(t.get_text() for t in labels) == sorted(
        f"{survey}:{text}"
        for survey in (1, 2)
        for text in ("S1 unfinished at 2.69 m", "S2 aborted at 1.00 m", "S3 unfinished at 0.50 m")
    )
    markers = [
        ax.transData.transform(xy)
        for c in ax.collections
        for xy in c.get_offsets()
        if c.get_label()
    ]
    for label in labels:
        box = label.get_window_extent(renderer)
        for x, y in markers:
            assert not box.contains(x, y), (label.get_text(), x, y)
