"""The simulator's bathymetric survey: the lines an autopilot flies, an echosounder that
errs as real ones do, and a day of soundings written straight into a journal."""

from __future__ import annotations

import itertools
import math
import random
import statistics
from collections import Counter
from pathlib import Path

import pytest

from cc_daemon.sim.autopilot import Autopilot, AutopilotConfig, Phase
from cc_daemon.sim.echosounder import EchoErrors, EchoKind, heave_m, read
from cc_daemon.sim.lines import SURVEY_SPEED_M_S, lines_route, make_lines_mission
from cc_daemon.sim.mission import SCALAR, from_lat_lon, make_mission
from cc_daemon.sim.nextsteps import map_steps
from cc_daemon.sim.options import SimOptions, autopilot_config
from cc_daemon.store import JournalReader
from tests.bathykit import lines_journal


def test_lines_run_back_and_forth_at_their_spacing() -> None:
    route = lines_route(20.0, 3, 100.0)
    assert [(p.east_m, p.north_m) for p in route] == [
        (0.0, 0.0), (100.0, 0.0), (100.0, 20.0), (0.0, 20.0), (0.0, 40.0), (100.0, 40.0),
    ]  # fmt: skip
    with pytest.raises(ValueError, match="spacing"):
        lines_route(0.0, 3, 100.0)


def test_the_lines_mission_passes_every_turn_and_casts_at_every_station() -> None:
    mission = make_lines_mission(3, 1, spacing_m=20.0, lines=4, line_length_m=100.0)
    assert mission.total_distance_m == pytest.approx(4 * 100 + 3 * 20)
    assert mission.stations[-1].point == lines_route(20.0, 4, 100.0)[-1]
    assert not any(s.too_shallow for s in mission.stations)
    assert all(s.water_depth_m > 1.0 for s in mission.stations)
    # The shoal is in the middle of the area, far from the stations: the map shows a hill.
    shoal = mission.field.shoal
    assert shoal is not None and 25.0 <= shoal.east_m <= 75.0
    assert mission.field.depth_at(shoal) == pytest.approx(0.6, abs=1e-9)
    # Along a leg the boat is on the lines, never cutting across.
    for i in range(3):
        for metres in range(0, int(mission.leg_length_m(i)), 7):
            p = mission.along_leg(i, metres)
            on_line = abs(p.north_m / 20.0 - round(p.north_m / 20.0)) < 1e-9
            at_turn = p.east_m in (0.0, 100.0)
            assert on_line or at_turn


def test_the_autopilot_sails_the_lines_at_survey_speed_in_any_pace() -> None:
    options = SimOptions(pattern="lines", lines=4, line_length_m=100.0)
    assert options.boat_speed_m_s == SURVEY_SPEED_M_S
    assert SimOptions().boat_speed_m_s == 80.0  # the stations' demo keeps its brisk transits
    from cc_daemon.config import Settings

    config = autopilot_config(options, Settings())
    assert config.boat_speed_m_s == SURVEY_SPEED_M_S
    mission = options.mission()
    pilot = Autopilot(mission, AutopilotConfig(boat_speed_m_s=1.5, firmware="manual"))
    frames = pilot.poll(0.0)
    assert pilot.to_go_m(0.0) == pytest.approx(mission.leg_length_m(0))
    assert pilot.to_go_m(10.0) == pytest.approx(mission.leg_length_m(0) - 15.0)
    now = 0.0
    while pilot.phase is Phase.CRUISING and now < 200.0:
        frames += pilot.poll(now)
        now += 0.25
    # A fix a second, 1.5 m apart: the density of a real survey.
    positions = [(f.lon_e7, f.lat_e7) for f in frames if f.frame == "P-T"]
    assert len(positions) > 100
    steps = [math.dist(a, b) for a, b in itertools.pairwise(positions)]
    assert max(steps) < 250  # degrees x 1e7: under 2 m
    assert pilot.phase is not Phase.CRUISING  # at S1, having sailed the lines to it


def test_the_depth_field_is_one_formula_for_numbers_and_arrays() -> None:
    np = pytest.importorskip("numpy")
    field = make_mission(3, 1).field
    east, north = np.linspace(-200, 200, 50), np.linspace(-100, 300, 50)
    grid = field.depth_xy(east, north, np)
    one = [field.depth_xy(float(e), float(n), SCALAR) for e, n in zip(east, north, strict=True)]
    assert grid.tolist() == pytest.approx(one, abs=1e-12)
    lat, lon = 40.451, -3.725
    e, n = from_lat_lon(lat, lon)
    from cc_daemon.sim.mission import to_lat_lon

    assert to_lat_lon(e, n) == pytest.approx((lat, lon), abs=1e-9)


def test_the_echosounder_errs_as_real_ones_do() -> None:
    errors = EchoErrors(outlier_rate=0.03, dropout_rate=0.05)
    rng = random.Random(5)
    readings = [read(6.0, 85.0, i * 0.25, rng, errors) for i in range(20_000)]
    kinds = Counter(r.kind for r in readings)
    assert kinds[EchoKind.DROPOUT] / 20_000 == pytest.approx(0.05, abs=0.006)
    outliers = kinds[EchoKind.SECOND_ECHO] + kinds[EchoKind.SHALLOW]
    assert outliers / 20_000 == pytest.approx(0.03, abs=0.005)
    for r in readings:
        if r.kind is EchoKind.DROPOUT:
            assert (r.distance_m, r.confidence_pct) == (0.0, 0)
        elif r.kind is EchoKind.SECOND_ECHO:
            assert 11.6 < r.distance_m < 12.4 and r.confidence_pct <= 75
        elif r.kind is EchoKind.SHALLOW:
            assert 1.4 <= r.distance_m <= 5.2 and r.confidence_pct <= 70
        else:
            assert abs(r.distance_m - 6.0) <= 0.03 + 0.06 + 1e-9 and r.confidence_pct == 85
    # Some bad readings keep a confidence a threshold would trust: the QC needs more.
    assert any(r.kind.outlier and r.confidence_pct >= 50 for r in readings)
    # Heave: a few centimetres, up and down, averaging out.
    heaves = [heave_m(i * 0.1, errors) for i in range(400)]
    assert max(heaves) == pytest.approx(0.03, abs=1e-3) and abs(sum(heaves) / 400) < 1e-3
    with pytest.raises(ValueError, match="outlier_rate"):
        EchoErrors(outlier_rate=1.5)


def test_a_lines_survey_goes_straight_into_a_journal_with_its_truth(tmp_path: Path) -> None:
    db = tmp_path / "lines.db"
    truth = lines_journal(db, lines=3, line_length_m=60.0, glitch_rate=0.05)
    with JournalReader(db) as reader:
        fixes = reader.fixes()
        readings = reader.sonar_readings()
        casts = reader.casts()
        (survey,) = reader.surveys()
    assert len(fixes) == truth.fixes and len(readings) == truth.pings
    assert abs(truth.pings - 2 * (truth.fixes - 3)) <= 1  # 4 readings a second, 2 fixes
    assert len(casts) == truth.casts == 3 and survey.simulated
    assert {r.session_id for r in readings} == {fixes[0].session_id}
    dropouts = [f for f, k in zip(fixes, truth.fix_kinds, strict=True) if k is EchoKind.DROPOUT]
    assert all(f.sonar_distance_m == 0.0 for f in dropouts)
    # One and two soundings a second, 1.5 m/s: a fix every 0.75 m along the line.
    assert fixes[2].wall_s - fixes[1].wall_s == pytest.approx(0.5)
    assert sum(truth.jumped) >= 1


def test_the_simulator_names_the_map_at_its_end(tmp_path: Path) -> None:
    steps = map_steps(tmp_path / "simulate.db", argv0="/x/cc-daemon", cwd=tmp_path)
    assert steps[0] == "/x/cc-daemon map --db simulate.db -o simulate-map"
    assert "bathymetry.nc" in steps[1] and "hypsography.csv" in steps[1]


async def test_a_lines_survey_end_to_end_has_a_real_surveys_density_and_maps(
    tmp_path: Path,
) -> None:
    """The real daemon against the simulated autopilot flying two short lines at the fast
    pace: the journal holds a fix every 1.65 m (not one every 88 m), and it maps."""
    import io

    pytest.importorskip("scipy")
    from cc_daemon.export.bathymap import MapOptions, make_map
    from cc_daemon.sim.runner import run_simulation

    out = io.StringIO()
    db = tmp_path / "lines.db"
    code = await run_simulation(
        SimOptions(
            pattern="lines",
            lines=2,
            line_length_m=20.0,
            spacing_m=10.0,
            stations=1,
            db=db,
            live=False,
            out=out,
            handle_signals=False,
        )
    )
    text = out.getvalue()
    # The protocol's verdict is the other simulator tests' to judge (a loaded machine can
    # hold an R-M past the autopilot's 3 s check); here, what the lines give the map.
    assert code in (0, 1), text
    assert "S1" in text and "SURVEY HALTED" not in text
    assert "(2 lines of 20 m, 10 m apart, at 1.5 m/s)" in text
    assert f"map --db {db} -o {tmp_path / 'lines-map'}" in text
    with JournalReader(db) as reader:
        fixes = [f for f in reader.fixes() if f.frame == "P-T"]
        survey = reader.select_survey("latest")
        assert survey is not None
        made = make_map(reader, survey, MapOptions(cell_m=2.0, max_distance_m=8.0))
    assert len(fixes) >= 25  # 50 m of lines at 1.5 m/s, a fix every 1.1 s
    steps = [
        math.dist(
            (a.lat_deg * 111_320, a.lon_deg * 84_800), (b.lat_deg * 111_320, b.lon_deg * 84_800)
        )
        for a, b in itertools.pairwise(fixes)
    ]
    # A fix a frame: the autopilot sends one a second and never catches up on one it
    # was late for (a loaded machine: 3.3 m once), so the spacing is judged by its median.
    assert statistics.median(steps) < 2.5
    assert made.simulated and made.bed.grid.mapped_cells > 20


def test_the_lines_options_on_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    import argparse

    from cc_daemon.sim.commands import add_simulate_arguments, options_from_args

    parser = argparse.ArgumentParser()
    parser.add_argument("--db", type=Path)
    add_simulate_arguments(parser)
    args = parser.parse_args(
        ["--pattern", "lines", "--spacing", "15", "--lines", "3", "--line-length", "50"]
    )
    options = options_from_args(args, None)
    assert (options.pattern, options.spacing_m, options.lines, options.line_length_m) == (
        "lines", 15.0, 3, 50.0,
    )  # fmt: skip
    assert options.mission().total_distance_m == pytest.approx(3 * 50 + 2 * 15)
    assert options_from_args(parser.parse_args([]), None).mission() == make_mission(3, 1)
    for bad in (["--spacing", "0"], ["--pattern", "spiral"], ["--lines", "0"]):
        with pytest.raises(SystemExit):
            parser.parse_args(bad)
        assert "error" in capsys.readouterr().err
    with pytest.raises(ValueError, match="--pattern"):
        SimOptions(pattern="spiral")
