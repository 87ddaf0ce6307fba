"""The end of a simulated run, without a run: verdicts, hints, narration and next steps."""

from __future__ import annotations

import io
import shutil
import sys
from pathlib import Path

import pytest

from cc_daemon.config import Settings
from cc_daemon.core.protocol import Ack, DepthReport, FaultReport, Finished
from cc_daemon.sim.autopilot import Autopilot, AutopilotConfig, Phase
from cc_daemon.sim.commands import add_simulate_arguments, options_from_args
from cc_daemon.sim.console import SimConsole, summary_lines
from cc_daemon.sim.mission import make_mission
from cc_daemon.sim.nextsteps import live_steps, next_steps, profile_steps, program
from cc_daemon.sim.options import FAST, REALTIME, SimOptions, pace_changes
from cc_daemon.sim.runner import _headline
from cc_daemon.sim.session import PROGRESS_EVERY_S, Run
from cc_daemon.sim.summary import REARM_HINT, build_summary


def _run_with(depths_mm: list[int], *, stations: int = 2, check_plan: bool = True) -> Run:
    """A remote run (no daemon here) whose S1 got R-O, these R-M and an R-F."""
    mission = make_mission(stations, 1)
    autopilot = Autopilot(mission, AutopilotConfig(frame_period_s=0.5, check_plan=check_plan))
    now = 0.0
    while autopilot.phase is not Phase.REQUESTING:
        autopilot.poll(now)
        now += 0.5
    autopilot.on_frame(now, Ack(0))
    for depth_mm in depths_mm:
        now += 0.5
        autopilot.on_frame(now, DepthReport(0, depth_mm))
    autopilot.on_frame(now + 0.5, Finished(0, 0))
    return Run(mission, autopilot, SimConsole(io.StringIO(), live=False))


def _summary(run: Run) -> list[str]:
    summary = build_summary(run, casts=None, daemon_exit=None, db_path=None, log_path=None)
    return summary_lines(summary)


def test_a_remote_cast_cut_short_is_not_called_measured() -> None:
    run = _run_with([500, 1000, 500, 0])  # a stall at 1 m: no castable plan is that shallow
    summary = build_summary(run, casts=None, daemon_exit=None, db_path=None, log_path=None)
    assert summary.stations[0].verdict == "cut short at 1.00 m (aborted?)"
    assert summary.measured == 0
    deep = build_summary(
        _run_with([1000, 2500, 1000, 0]), casts=None, daemon_exit=None, db_path=None, log_path=None
    )
    assert deep.stations[0].verdict == "measured"
    # Without the plan check (a daemon configured otherwise) depth says nothing.
    unchecked = build_summary(
        _run_with([500, 1000, 0], check_plan=False),
        casts=None,
        daemon_exit=None,
        db_path=None,
        log_path=None,
    )
    assert unchecked.stations[0].verdict == "measured"


def test_an_immediate_r_f_at_a_deep_station_hints_at_the_rearm_window() -> None:
    lines = _summary(_run_with([]))  # R-O then R-F, no R-M: what a re-arm window answers
    assert any("deep station not cast" in line for line in lines)
    assert REARM_HINT in lines
    assert "cast.rearm_s" in REARM_HINT
    assert REARM_HINT not in _summary(_run_with([1000, 2500, 0]))


def test_the_last_line_says_both_the_survey_and_the_protocol() -> None:
    run = _run_with([1000, 2500, 0], stations=1)
    [last] = _summary(run)[-1:]
    assert last == (
        "SURVEY OK: 1 of 1 castable station measured; the daemon kept the protocol on the wire "
        "(exit status 0)"
    )
    short = _summary(_run_with([500, 1000, 0], stations=1))[-1]
    assert short == (
        "SURVEY INCOMPLETE: 0 of 1 castable station measured; the daemon kept the protocol on "
        "the wire (exit status 3)"
    )


def test_a_ctrl_c_before_any_cast_does_not_claim_the_probe_was_brought_home() -> None:
    mission = make_mission(2, 1)
    autopilot = Autopilot(mission, AutopilotConfig())
    autopilot.poll(0.0)
    run = Run(mission, autopilot, SimConsole(io.StringIO(), live=False))
    run.interrupts = 1
    autopilot.finish(1.0, interrupted=True)
    summary = build_summary(run, casts=[], daemon_exit=0, db_path=None, log_path=None)
    summary.probe_depth_m = 0.0
    summary.remote = False
    lines = summary_lines(summary)
    assert "interrupted before any cast: the probe never left home" in lines
    assert not any("brought the probe home" in line for line in lines)
    assert summary.exit_code == 3


def test_plain_output_says_the_boat_is_under_way_from_the_start_and_how_far_to_go() -> None:
    mission = make_mission(2, 1)
    autopilot = Autopilot(mission, AutopilotConfig(boat_speed_m_s=REALTIME.boat_speed_m_s))
    out = io.StringIO()
    run = Run(mission, autopilot, SimConsole(out, live=False))
    leg = mission.leg(0)[0].distance_to(mission.leg(0)[1])
    autopilot.poll(0.0)
    run._observe(0.0)
    first = out.getvalue().splitlines()
    assert first == [f"    0.0 s  under way to S1: {leg:.0f} m at 1.5 m/s, ETA {leg / 1.5:.0f} s"]
    autopilot.poll(PROGRESS_EVERY_S - 1)
    run._observe(PROGRESS_EVERY_S - 1)
    assert len(out.getvalue().splitlines()) == 1  # not yet
    autopilot.poll(PROGRESS_EVERY_S)
    run._observe(PROGRESS_EVERY_S)
    to_go = leg - PROGRESS_EVERY_S * 1.5
    assert out.getvalue().splitlines()[-1] == (
        f"   30.0 s  under way to S1: {to_go:.0f} m to go, ETA {to_go / 1.5:.0f} s"
    )


def test_the_header_lists_what_the_fast_pace_changed_and_real_pace_keeps_it() -> None:
    mine = Settings.model_validate({"cast": {"soak_s": 3.0, "dwell_s": 2.0}})
    changes = pace_changes(SimOptions(settings=mine))
    assert "cast.soak_s 3 -> 0" in changes
    assert "cast.dwell_s 2 -> 1" in changes
    assert "winch.sim.speed_m_s 0.25 -> 1.25" in changes
    # Its casts are not slowed for the profile: bins as thick as a reading's travel.
    assert "profile.bin_m 0.25 -> 1.25" in changes
    assert "profile.min_count 2 -> 1" in changes
    assert "profile.resolve [temperature] -> []" in changes
    assert pace_changes(SimOptions(settings=mine, realtime=True)) == []
    mission = make_mission(2, 1)
    head = _headline(SimOptions(settings=mine), mission).splitlines()
    assert head[1].startswith("  fast pace: boat 80 m/s; your settings changed: ")
    assert "cast.soak_s 3 -> 0" in head[1]
    assert head[1].endswith("(--pace real keeps them)")
    real = _headline(SimOptions(settings=mine, realtime=True), mission).splitlines()
    assert (
        real[1] == "  real pace: boat 1.5 m/s; your winch, cast and profile settings as configured"
    )
    # Settings that already agree with the pace are not reported as changed.
    same = Settings.model_validate(
        {
            "cast": dict(FAST.cast),
            "winch": {"sim": {"speed_m_s": FAST.winch_speed_m_s}},
            "profile": {"bin_m": 1.25, "min_count": 1, "resolve": []},
        }
    )
    assert pace_changes(SimOptions(settings=same)) == []


def test_pace_real_and_realtime_are_one_option() -> None:
    import argparse

    parser = argparse.ArgumentParser()
    parser.add_argument("--db", type=Path)
    add_simulate_arguments(parser)
    for argv in (["--pace", "real"], ["--realtime"]):
        assert options_from_args(parser.parse_args(argv), None).chosen_pace is REALTIME
    assert options_from_args(parser.parse_args([]), None).chosen_pace is FAST
    with pytest.raises(SystemExit):
        parser.parse_args(["--pace", "slow"])


def test_next_steps_are_runnable_as_printed(tmp_path: Path) -> None:
    venv_program = tmp_path / ".venv" / "bin" / "cc-daemon"
    assert program(str(venv_program), cwd=tmp_path) == ".venv/bin/cc-daemon"
    assert program("cc-daemon-x", cwd=tmp_path).endswith(" -m cc_daemon")
    assert program("cc-daemon-x", cwd=tmp_path).startswith(str(Path(sys.executable)))
    on_path = shutil.which("cc-daemon")
    if on_path is not None:
        assert program(on_path, cwd=tmp_path) == "cc-daemon"
    # A clone: its Makefile has the targets, the journal is its ./simulate.db.
    (tmp_path / "Makefile").write_text("export:\n\ttrue\nplot:\n\ttrue\n")
    steps = next_steps(tmp_path / "simulate.db", 2, argv0=str(venv_program), cwd=tmp_path)
    assert steps == [
        ".venv/bin/cc-daemon casts --db simulate.db",
        ".venv/bin/cc-daemon export --db simulate.db --format csv -o simulate.csv",
        ".venv/bin/cc-daemon sonde export --db simulate.db --format csv -o simulate-sonde.csv",
        ".venv/bin/cc-daemon plot --db simulate.db --survey -o simulate-survey.png",
        ".venv/bin/cc-daemon plot --db simulate.db --cast 2 -o simulate-cast-2.png",
        ".venv/bin/cc-daemon web --db simulate.db   (the field page: open the address it prints)",
        "make export plot   (CSV, GeoJSON, NetCDF and the survey map, beside it)",
    ]
    watch = live_steps(tmp_path / "simulate.db", tmp_path / "x.sock", True, argv0=str(
        venv_program), cwd=tmp_path)  # fmt: skip
    assert watch == [
        ".venv/bin/cc-daemon status --db simulate.db --watch",
        ".venv/bin/cc-daemon web --db simulate.db",
    ]
    aside = live_steps(tmp_path / "simulate.db", tmp_path / "run" / "status.sock", False,
                       argv0=str(venv_program), cwd=tmp_path)  # fmt: skip
    assert aside == [
        ".venv/bin/cc-daemon status --socket run/status.sock --watch",
        ".venv/bin/cc-daemon web --db simulate.db --socket run/status.sock",
    ]
    elsewhere = next_steps(Path("/data/a b.db"), None, argv0=str(venv_program), cwd=tmp_path)
    assert elsewhere[0] == ".venv/bin/cc-daemon casts --db '/data/a b.db'"
    assert not any(step.startswith("make") for step in elsewhere)
    profiles = profile_steps(tmp_path / "simulate.db", argv0=str(venv_program), cwd=tmp_path)
    assert profiles[0] == ".venv/bin/cc-daemon profiles --db simulate.db -o simulate-profiles"
    assert profiles[1].startswith("  makes simulate-profiles/: profiles.nc and profiles.csv")
    assert profile_steps(Path("/data/a b.db"), argv0=str(venv_program), cwd=tmp_path)[0] == (
        ".venv/bin/cc-daemon profiles --db '/data/a b.db' -o '/data/a b-profiles'"
    )


def test_the_headline_counts_stations_in_english() -> None:
    assert _headline(SimOptions(stations=1), make_mission(1, 1)).startswith(
        "cc-daemon --simulate: 1 station, seed 1, fast pace, "
    )
    assert _headline(SimOptions(), make_mission(3, 1)).startswith(
        "cc-daemon --simulate: 3 stations, seed 1, "
    )


def test_a_probe_stranded_with_r_l_halts_the_survey_with_its_own_exit_status() -> None:
    mission = make_mission(2, 1)
    autopilot = Autopilot(mission, AutopilotConfig(frame_period_s=0.5))
    now = 0.0
    while autopilot.phase is not Phase.REQUESTING:
        autopilot.poll(now)
        now += 0.5
    autopilot.on_frame(now, Ack(0))
    for depth_mm in (1000, 2000):
        now += 0.5
        autopilot.on_frame(now, DepthReport(0, depth_mm))
    for _ in range(4):  # stuck at 1.5 m hauling in: R-L, never R-F
        now += 0.5
        autopilot.on_frame(now, FaultReport(0, 1500))
    autopilot.finish(now + 0.5)  # the run ends with the station held
    run = Run(mission, autopilot, SimConsole(io.StringIO(), live=False))
    summary = build_summary(run, casts=None, daemon_exit=None, db_path=None, log_path=None)
    lines = summary_lines(summary)
    assert summary.exit_code == 4 and summary.stranded_at == 1
    assert lines[-1] == (
        "SURVEY HALTED: probe stranded at S1, fault reported to the autopilot: 0 of 1 castable "
        "station measured; the daemon kept the protocol on the wire (exit status 4)"
    )
    assert summary.stations[0].verdict == "stranded: R-L x4, no R-F"
    assert [v.excused_by for v in summary.violations] == ["the daemon reported the fault (R-L)"]


def test_a_cast_the_journal_holds_is_measured_though_its_r_m_were_lost_on_the_cable() -> None:
    from cc_daemon.sim.summary import JournalCast

    mission = make_mission(2, 1)
    autopilot = Autopilot(mission, AutopilotConfig(frame_period_s=0.5))
    now = 0.0
    while autopilot.phase is not Phase.REQUESTING:
        autopilot.poll(now)
        now += 0.5
    autopilot.on_frame(now, Ack(0))
    autopilot.link_down(now + 0.5)
    autopilot.link_up(now + 3.5)
    autopilot.on_frame(now + 8.0, Finished(0, 0))
    run = Run(mission, autopilot, SimConsole(io.StringIO(), live=False))
    casts = [JournalCast(1, 2.64, 2.64, "completed", None, 1)]
    summary = build_summary(run, casts=casts, daemon_exit=0, db_path=None, log_path=None)
    assert summary.stations[0].verdict == "measured" and summary.protocol_kept
    assert any("the journal holds the cast, completed" in note for note in summary.notes)
