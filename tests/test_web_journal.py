"""The field page's JSON for "Today" (issue 29): the survey's map in the frame, and with
the origin, that `cc-daemon plot --survey` draws it in; stations named as everywhere
else; a thinned track; a cast's depths with their estimates; the sonde's units."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from cc_daemon.cli.web import journaldata
from cc_daemon.export.mapframe import LocalFrame
from cc_daemon.store import JournalReader
from cc_daemon.store.synthetic import FakeClock
from cc_daemon.store.track import track
from tests import webkit
from tests.test_estimates import _survey


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return webkit.make_journal(tmp_path_factory.mktemp("web") / "j.db")


def test_the_map_is_drawn_in_the_survey_plots_frame(journal: Path) -> None:
    data = journaldata.survey_casts(journal, 2)
    with JournalReader(journal) as reader:
        reader.select_survey(2)
        casts, fixes = reader.casts(), reader.fixes()
    frame = LocalFrame.around(
        [f.lat_deg for f in fixes] + [c.lat_deg for c in casts],
        [f.lon_deg for f in fixes] + [c.lon_deg for c in casts],
    )  # as plot.survey_figure makes it
    assert data["origin"] == frame.origin_text()
    assert [c["station"] for c in data["casts"]] == [f"S{n + 1}" for n in range(len(casts))]
    for row, cast in zip(data["casts"], casts, strict=True):
        assert row["east_m"] == pytest.approx(frame.east_m(cast.lon_deg), abs=0.01)
        assert row["north_m"] == pytest.approx(frame.north_m(cast.lat_deg), abs=0.01)
    assert [s["name"] for s in data["stations"]] == [c["station"] for c in data["casts"]]
    # 1,800 fixes thinned to at most about 2,000 points, the first and the last kept.
    assert 2 <= len(data["track"]) <= 2001
    for point, fix in ((data["track"][0], fixes[0]), (data["track"][-1], fixes[-1])):
        where = (frame.east_m(fix.lon_deg), frame.north_m(fix.lat_deg))
        assert tuple(point) == pytest.approx(where, abs=0.01)


def test_a_long_track_is_thinned_and_keeps_its_ends(journal: Path) -> None:
    with JournalReader(journal) as reader:
        reader.select_survey(2)
        fixes = reader.fixes()
        sailed = track(reader, 2, max_points=100)
    assert 50 <= len(sailed.points) <= 102
    assert sailed.points[0] == (fixes[0].lat_deg, fixes[0].lon_deg)
    assert sailed.points[-1] == (fixes[-1].lat_deg, fixes[-1].lon_deg)
    assert sailed.extent is not None and sailed.extent.fixes == len(fixes)
    assert sailed.extent.min_lat == min(f.lat_deg for f in fixes)


def test_a_profile_gives_each_depth_as_measured_or_as_an_estimate(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    ids = _survey(db, FakeClock())
    profile = journaldata.cast_profile(db, ids["dead"])
    assert profile["cast"]["station"] == "S1"
    depths = [(s["depth_m"], s["low_m"], s["high_m"], s["sampled"]) for s in profile["samples"]]
    assert depths[:4] == [(0.0, None, None, True), (1.3, None, None, True),
                          (2.686, None, None, True), (2.686, None, None, True)]  # fmt: skip
    assert depths[4] == (0.244, 0.0, 2.686, False)  # the winch's depth at the fault
    assert depths[5:] == [(0.244, 0.0, 2.686, True)] * 4
    stall = journaldata.cast_profile(db, ids["stall"])
    assert max(s["depth_m"] for s in stall["samples"]) == 1.0  # the stall, between samples


def test_the_sonde_s_parameters_come_with_their_units(journal: Path) -> None:
    with JournalReader(journal) as reader:
        cast = [c for c in reader.casts() if c.outcome == "completed"][-1]
    profile = journaldata.cast_profile(journal, cast.id)
    units = {p["name"]: p["unit"] for p in profile["parameters"]}
    assert units["temperature"] == "degC" and units["do_concentration"] == "mg/L"
    assert [r["phase"] for r in profile["sonde"]] == ["descending"] * 8
    latest = journaldata.latest(journal, time.time())
    assert {p["name"]: p["unit"] for p in latest["parameters"]}["chlorophyll"] == "RFU"
