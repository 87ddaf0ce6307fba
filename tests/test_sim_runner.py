"""`--simulate` end to end: the real daemon in-process, the simulated autopilot, a pty."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import os
import signal
import time
from pathlib import Path

import pytest

from cc_daemon.config import Settings
from cc_daemon.service import Daemon
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.runner import (
    FAST,
    AutopilotOnlyOptions,
    Pace,
    SimOptions,
    add_commands,
    add_simulate_arguments,
    daemon_settings,
    options_from_args,
    plan_is_predictable,
    run_autopilot,
    run_simulation,
)
from cc_daemon.store import JournalReader

# Faster than the demo, for the tests that are about behaviour, not looks.
QUICK = Pace(
    "quick",
    frame_period_s=0.25,
    boat_speed_m_s=300.0,
    winch_speed_m_s=2.0,
    cast={
        "bottom_dwell_s": 0.5,
        "report_period_s": 0.5,
        "max_duration_s": 20.0,
        "target_depth_m": 2.0,
    },
)


async def _simulate(tmp_path: Path, **options: object) -> tuple[int, str, float]:
    out = io.StringIO()
    started = time.monotonic()
    code = await run_simulation(
        SimOptions(
            db=tmp_path / "survey.db",
            live=False,
            out=out,
            handle_signals=False,
            **options,  # type: ignore[arg-type]
        )
    )
    return code, out.getvalue(), time.monotonic() - started


def _casts(tmp_path: Path) -> list[tuple[str | None, float, float | None]]:
    with JournalReader(tmp_path / "survey.db") as reader:
        return [(c.outcome, c.planned_depth_m, c.reached_depth_m) for c in reader.casts()]


def _row(text: str, station: str) -> str:
    """The station's row in the summary table (not its line in the mission listing)."""
    return next(
        line
        for line in text.splitlines()
        if line.strip().startswith(station + " ") and " N " in line
    )


async def test_a_two_station_survey_at_demo_pace(tmp_path: Path) -> None:
    code, text, elapsed = await _simulate(tmp_path, stations=2, pace=FAST)
    assert code == 0, text
    assert elapsed < 25
    assert "SURVEY OK (exit status 0)" in text
    assert "protocol violations: 0" in text
    assert "measured" in _row(text, "S1")
    assert "skipped: too shallow" in _row(text, "S2")
    assert f"export it: cc-daemon export --db {tmp_path / 'survey.db'} --format csv" in text
    assert "daemon: 1 cast(s) completed, 0 aborted, 1 skipped" in text
    outcomes = [outcome for outcome, _, _ in _casts(tmp_path)]
    assert outcomes == ["completed", "skipped-shallow"]
    assert (tmp_path / "survey.log").read_text().count('"event": "cast started"') == 1


async def test_m_resent_throughout_the_cast_still_gives_one_cast_per_station(
    tmp_path: Path,
) -> None:
    code, text, _ = await _simulate(tmp_path, stations=3, seed=4, pace=QUICK, resend_m=True)
    assert code == 0, text
    casts = _casts(tmp_path)
    assert [outcome for outcome, _, _ in casts] == ["completed", "skipped-shallow", "completed"]
    m_count = int(text.split(" to the daemon (")[1].split(" M)")[0])
    assert m_count > 10  # many M frames, still one cast each


async def test_a_winch_stall_aborts_and_the_probe_comes_home_before_r_f(tmp_path: Path) -> None:
    code, text, _ = await _simulate(tmp_path, stations=2, pace=QUICK, winch_stall=True)
    assert code == 0, text
    row = _row(text, "S1")
    assert "aborted: stall at 1.00 m" in row
    assert row.split()[9:11] == ["1.00", "m"]  # reached: where it stalled
    assert "0 cast(s) completed, 1 aborted, 1 skipped" in text
    outcome, _, reached = _casts(tmp_path)[0]
    assert outcome == "aborted"
    assert reached == pytest.approx(1.0, abs=0.01)


async def test_a_pulled_cable_mid_cast_is_survived(tmp_path: Path) -> None:
    slow_winch = Pace(
        "quick",
        frame_period_s=0.25,
        boat_speed_m_s=300.0,
        winch_speed_m_s=0.5,
        cast={"bottom_dwell_s": 0.5, "max_duration_s": 40.0, "target_depth_m": 2.0},
    )
    code, text, _ = await _simulate(
        tmp_path, stations=2, pace=slow_winch, drop_link_at=2.0, drop_link_for=1.5
    )
    assert code == 0, text
    assert "cable pulled for 1.5 s" in text
    assert "cable plugged back in" in text
    assert "cable pulled 1 time(s); the daemon lost its port 1 time(s) and reopened it" in text
    assert "the cable was unplugged" in text  # the silence is explained, not a violation
    assert [outcome for outcome, _, _ in _casts(tmp_path)] == ["completed", "skipped-shallow"]


async def test_bit_flips_both_ways_are_counted_and_the_survey_completes(tmp_path: Path) -> None:
    code, text, _ = await _simulate(tmp_path, stations=2, pace=QUICK, corrupt=0.02, seed=2)
    assert code == 0, text
    line = next(x for x in text.splitlines() if x.startswith("corrupt frames:"))
    rejected = int(line.split(", ")[1].split(" rejected")[0])
    assert rejected > 0
    assert "bits flipped towards the daemon" in line
    assert [outcome for outcome, _, _ in _casts(tmp_path)] == ["completed", "skipped-shallow"]


async def test_ctrl_c_mid_cast_brings_the_probe_home_and_prints_the_summary(
    tmp_path: Path,
) -> None:
    slow_winch = Pace("quick", 0.25, 300.0, 0.4, cast={"bottom_dwell_s": 5.0})
    loop = asyncio.get_running_loop()
    timer = loop.call_later(3.0, os.kill, os.getpid(), signal.SIGINT)
    try:
        out = io.StringIO()
        code = await run_simulation(
            SimOptions(
                stations=2,
                pace=slow_winch,
                db=tmp_path / "survey.db",
                live=False,
                out=out,
                handle_signals=True,
            )
        )
    finally:
        timer.cancel()
    text = out.getvalue()
    assert code == 1, text
    assert "Ctrl-C: the daemon brings the probe home, then stops" in text
    assert "aborted: shutdown" in _row(text, "S1")
    assert "not reached" in _row(text, "S2")
    assert "interrupted: the daemon brought the probe home before stopping" in text
    assert "← R-F" in text
    assert [outcome for outcome, _, _ in _casts(tmp_path)] == ["aborted"]


async def test_a_probe_that_cannot_come_home_gets_no_r_f_and_fails_the_run(
    tmp_path: Path,
) -> None:
    jamming = Pace(
        "quick",
        frame_period_s=0.25,
        boat_speed_m_s=300.0,
        winch_speed_m_s=2.0,
        cast={"bottom_dwell_s": 0.5, "max_duration_s": 3.0, "target_depth_m": 2.0},
        finish_margin_s=3.0,
    )
    code, text, _ = await _simulate(tmp_path, stations=2, pace=jamming, winch_fail_home=True)
    assert code == 130, text  # the daemon was stopped at once, the probe still down
    assert "no R-F" in _row(text, "S1")
    assert "not reached" in _row(text, "S2")
    assert "giving up on the station with the probe last reported at 0.50 m" in text
    assert "← R-F" not in text  # never told to leave with the probe down
    assert "SURVEY FAILED (exit status 130)" in text


def test_the_daemon_settings_for_a_run(tmp_path: Path) -> None:
    base = Settings.model_validate({"cast": {"target_depth_m": 4.0}, "store": {"path": "/x.db"}})
    options = SimOptions(db=tmp_path / "s.db", settings=base, winch_stall=True)
    settings = daemon_settings(options, tmp_path / "tty")
    assert settings.serial.port == str(tmp_path / "tty")
    assert settings.store.path == tmp_path / "s.db"
    assert settings.winch.sim.stall_at_m == 1.0
    assert settings.winch.sim.speed_m_s == FAST.winch_speed_m_s
    assert settings.cast.target_depth_m == 4.0  # the base settings are kept
    assert settings.cast.bottom_dwell_s == FAST.cast["bottom_dwell_s"]
    realtime = daemon_settings(SimOptions(realtime=True), tmp_path / "tty")
    assert realtime.winch.sim.speed_m_s == Settings().winch.sim.speed_m_s
    assert realtime.cast == Settings().cast


def test_the_plan_check_follows_the_cast_settings() -> None:
    assert plan_is_predictable(Settings().cast)
    wide_clearance = Settings.model_validate({"cast": {"bottom_clearance_m": 2.5}}).cast
    assert not plan_is_predictable(wide_clearance)
    distrustful = Settings.model_validate({"cast": {"min_sonar_confidence": 99}}).cast
    assert not plan_is_predictable(distrustful)


def test_the_command_line_options(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--db", type=Path)
    add_simulate_arguments(parser)
    sub = parser.add_subparsers(dest="command")
    add_commands(sub)
    args = parser.parse_args(
        [
            *("--stations", "5", "--seed", "9", "--corrupt", "0.01", "--drop-link-at", "12"),
            *("--winch-stall", "--resend-m", "--plain", "--db", str(tmp_path / "d.db")),
        ]
    )
    options = options_from_args(args, None)
    assert (options.stations, options.seed, options.corrupt) == (5, 9, 0.01)
    assert (options.drop_link_at, options.drop_link_for) == (12.0, 3.0)
    assert options.winch_stall
    assert options.resend_m
    assert options.live is False
    assert options.db_path == tmp_path / "d.db"
    assert options.log_path == tmp_path / "d.log"
    assert options.chosen_pace is FAST
    assert SimOptions(realtime=True).chosen_pace.frame_period_s == 1.0

    args = parser.parse_args(["simulate-autopilot", "--port", "/dev/ttyUSB0", "--seed", "3"])
    assert args.port == "/dev/ttyUSB0"
    assert args.baudrate == 9600
    assert callable(args.handler)


@pytest.mark.parametrize(
    "argv",
    [["--corrupt", "2"], ["--stations", "0"], ["--drop-link-at", "-1"]],
)
def test_bad_option_values_are_refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    add_simulate_arguments(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(argv)
    assert "error" in capsys.readouterr().err


async def test_simulate_autopilot_on_a_serial_port_against_a_daemon(tmp_path: Path) -> None:
    # Two pty pairs joined master to master make a null-modem cable with a
    # device node at each end: the daemon opens one, simulate-autopilot the other.
    with PtyPair(tmp_path / "ttyPI") as pi_end, PtyPair(tmp_path / "ttyLAPTOP") as laptop_end:
        loop = asyncio.get_running_loop()

        def relay(src: int, dst: int) -> None:
            with contextlib.suppress(BlockingIOError):
                os.write(dst, os.read(src, 4096))

        loop.add_reader(pi_end.master_fd, relay, pi_end.master_fd, laptop_end.master_fd)
        loop.add_reader(laptop_end.master_fd, relay, laptop_end.master_fd, pi_end.master_fd)
        settings = Settings.model_validate(
            {
                "serial": {"port": str(pi_end.path)},
                "winch": {"sim": {"speed_m_s": 2.0}},
                "cast": {"target_depth_m": 2.0, "bottom_dwell_s": 0.5},
                "store": {"path": str(tmp_path / "pi.db")},
            }
        )
        daemon = Daemon(settings)
        daemon_task = asyncio.create_task(daemon.run())
        try:
            await asyncio.wait_for(daemon.ready.wait(), 10)
            out = io.StringIO()
            code = await run_autopilot(
                AutopilotOnlyOptions(
                    port=str(laptop_end.path),
                    stations=2,
                    frame_period_s=0.25,
                    boat_speed_m_s=300.0,
                    out=out,
                    live=False,
                    handle_signals=False,
                )
            )
        finally:
            daemon.request_shutdown()
            await asyncio.wait_for(daemon_task, 10)
            loop.remove_reader(pi_end.master_fd)
            loop.remove_reader(laptop_end.master_fd)
    text = out.getvalue()
    assert code == 0, text
    assert f"simulate-autopilot on {laptop_end.path} at 9600 baud" in text
    assert "measured" in _row(text, "S1")
    assert "skipped: too shallow" in _row(text, "S2")
    assert "data stored" not in text  # the journal is on the other machine
    assert daemon.snapshot().casts_completed == 1
