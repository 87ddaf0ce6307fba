"""`--simulate` end to end: the real daemon in-process, the simulated autopilot, a pty."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from cc_daemon.config import Settings
from cc_daemon.core.protocol import DepthReport, ErrorKind, Finished, encode
from cc_daemon.daemon.service import Daemon
from cc_daemon.sim import mission as mission_module
from cc_daemon.sim.autopilot import Autopilot, AutopilotConfig
from cc_daemon.sim.commands import (
    EXIT_USAGE,
    add_commands,
    add_simulate_arguments,
    options_from_args,
    run_from_args,
)
from cc_daemon.sim.console import SimConsole
from cc_daemon.sim.logtap import LogTap
from cc_daemon.sim.mission import make_mission
from cc_daemon.sim.options import (
    FAST,
    REALTIME,
    AutopilotOnlyOptions,
    Pace,
    SimOptions,
    autopilot_config,
    daemon_settings,
    plan_is_predictable,
)
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.runner import run_autopilot, run_simulation
from cc_daemon.sim.session import Run
from cc_daemon.sim.summary import build_summary
from cc_daemon.sim.violations import BITS_FLIPPED, ViolationKind
from cc_daemon.store import JournalReader
from tests.daemonkit import START_S, WAIT_S
from tests.waitkit import until

REPO = Path(__file__).resolve().parent.parent

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
    """Its exit status, its plain output and how long it took (for a figure, never a
    test's verdict: a busy machine stretches a run)."""
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


def _reached(row: str) -> float:
    """The "reached" column of a summary row (station, lat N, lon W, water, planned, reached)."""
    cells = row.split()
    assert cells[10] == "m", row
    return float(cells[9])


def test_the_demo_sends_one_frame_a_second_as_the_firmware_does() -> None:
    assert FAST.frame_period_s == 1.0
    assert REALTIME.frame_period_s == 1.0


@pytest.mark.parametrize("firmware", ["ucm-2023", "manual"])
async def test_a_two_station_survey_at_demo_pace(tmp_path: Path, firmware: str) -> None:
    # (How long the demo takes is a figure of the README, measured: a test never
    # times a run, which a busy machine stretches.)
    code, text, _ = await _simulate(tmp_path, stations=2, pace=FAST, firmware=firmware)
    assert code == 0, text
    # The 2023 firmware: T every 1.1 s and a stick jog at the deepest station first.
    assert "corrupt frames: 0 from the daemon, 0 rejected by the daemon" in text
    jogged = "S1: stick jog before the station: 1 P-D then 3 P-U frames (no reply expected)"
    assert (jogged in text) == (firmware == "ucm-2023")
    assert (
        "SURVEY OK: 1 of 1 castable station measured; the daemon kept the protocol (exit status 0)"
    ) in text
    assert "protocol violations: 0" in text
    assert "measured" in _row(text, "S1")
    assert "skipped: too shallow" in _row(text, "S2")
    # Runnable as printed: here (pytest) the Python that runs us, with -m cc_daemon.
    db, csv = tmp_path / "survey.db", tmp_path / "survey.csv"
    assert f" -m cc_daemon export --db {db} --format csv -o {csv}\n" in text
    assert f" -m cc_daemon plot --db {db} --cast 1 -o {tmp_path / 'survey-cast-1.png'}\n" in text
    assert "daemon: 1 cast(s) completed, 0 aborted, 1 skipped, 0 unfinished\n" in text
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
    assert code == 3, text  # the daemon did right, but the station was not measured
    assert text.endswith(
        "SURVEY INCOMPLETE: 0 of 1 castable station measured; the daemon kept the protocol "
        "(exit status 3)\n"
    )
    row = _row(text, "S1")
    assert "aborted: stall at 1.00 m" in row
    assert _reached(row) == pytest.approx(1.0, abs=0.05)  # where it stalled, not the last R-M
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
    # Timed for the manual's autopilot (no stick jog before S1 to shift the cast).
    code, text, _ = await _simulate(
        tmp_path,
        stations=2,
        pace=slow_winch,
        drop_link_at=2.0,
        drop_link_for=1.5,
        firmware="manual",
    )
    assert code == 0, text
    assert "cable pulled for 1.5 s" in text
    assert "cable plugged back in" in text
    assert "cable pulled 1 time(s); the daemon lost its port 1 time(s) and reopened it" in text
    assert "the cable was unplugged" in text  # the silence is explained, not a violation
    casts = _casts(tmp_path)
    assert [outcome for outcome, _, _ in casts] == ["completed", "skipped-shallow"]
    # The reports from the bottom were lost with the cable; the probe went there all the same.
    journal_reached = casts[0][2]
    assert journal_reached == pytest.approx(2.0, abs=0.01)
    assert _reached(_row(text, "S1")) == pytest.approx(journal_reached, abs=0.005)


async def test_bit_flips_both_ways_are_counted_and_each_fault_they_cause_is_excused(
    tmp_path: Path,
) -> None:
    # Heavy noise: a dozen frames to the daemon spoilt in a few seconds, a few back.
    # The manual's autopilot, which resends M: the 2023 firmware sends M once and
    # waits for ever, so a spoilt M strands it (the daemon can only say so).
    code, text, _ = await _simulate(
        tmp_path, stations=2, pace=QUICK, corrupt=0.06, seed=7, firmware="manual"
    )
    assert code == 0, text
    line = next(x for x in text.splitlines() if x.startswith("corrupt frames:"))
    from_daemon = int(line.split(": ")[1].split(" from")[0])
    rejected = int(line.split(", ")[1].split(" rejected")[0])
    assert from_daemon > 0
    assert rejected > 0
    assert "bits flipped towards the daemon" in line
    # Every violation was caused by a flip near it; none is left on the daemon's account.
    assert "protocol violations: 0 (+" in text
    assert "excused: " in text
    assert "corrupt frame (bits flipped by --corrupt)" in text
    assert [outcome for outcome, _, _ in _casts(tmp_path)] == ["completed", "skipped-shallow"]


class FlipAt:
    """Line noise at chosen bytes of the stream (offset -> bits), as the simulator's
    `BitFlipper` does it: each flip timed with the clock, inside the port's read."""

    def __init__(self, flips: dict[int, int]) -> None:
        self.flips = flips
        self.bytes_seen = 0
        self.flip_times: list[float] = []

    def __call__(self, data: bytes) -> bytes:
        out = bytearray(data)
        for offset, bits in self.flips.items():
            if self.bytes_seen <= offset < self.bytes_seen + len(data):
                out[offset - self.bytes_seen] ^= bits
                self.flip_times.append(time.monotonic())
        self.bytes_seen += len(data)
        return bytes(out)


@pytest.mark.parametrize("case", ["a good frame then a spoilt one in one read", "a cascade"])
async def test_every_corrupt_frame_a_flip_made_is_excused(tmp_path: Path, case: str) -> None:
    # Found under load (issue 31), a run judged PROTOCOL VIOLATED by its own noise. A
    # flip is timed inside the read, a moment before the read's frames are: a frame
    # spoilt after a good one in the same read had a window (from that good frame to
    # now) that missed the flip. And one flip that made an R-M's checksum byte 0x52
    # ('R') spoilt two frames: the R-M, then "52 52" with the next frame's sync byte,
    # as the parser read on through it; the second's window opened after the flip.
    if case == "a cascade":
        first = encode(DepthReport(4, 47))  # its checksum byte is 0xD2: flipped, 0x52
        writes = [first, encode(Finished(4, 0))]
        flips = {len(first) - 1: 0x80}
        corrupt = [ErrorKind.BAD_CHECKSUM, ErrorKind.UNKNOWN_TYPE]
    else:
        writes = [b"\x00", encode(DepthReport(4, 47)) + encode(DepthReport(5, 48))]
        flips = {12: 0x01}  # in the second R-M of the second read
        corrupt = [ErrorKind.BAD_CHECKSUM]
    mission = make_mission(2, 1)
    autopilot = Autopilot(mission, AutopilotConfig(boat_speed_m_s=300.0))
    console = SimConsole(io.StringIO(), live=False)
    with PtyPair(tmp_path / "tty") as pair:
        run = Run(mission, autopilot, console, pair=pair, flip_in=FlipAt(flips))  # type: ignore[arg-type]
        await run.attach_pty()
        port = run.port
        assert port is not None
        slave = os.open(pair.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            written = 0
            for data in writes:  # one read each: the next is written once it is read
                os.write(slave, data)
                written += len(data)
                await until(lambda n=written: port.bytes_in == n, what="the write read")
            await run.collect()  # as the run takes them: flips, errors, frames
        finally:
            os.close(slave)
            await run.close()
    assert [e.kind for e in port.errors] == corrupt
    judged = [v for v in autopilot.violations if v.kind is ViolationKind.CORRUPT_FRAME]
    assert [v.excused_by for v in judged] == [BITS_FLIPPED] * len(corrupt)


Moment = Callable[[str], bool]  # on the run's output so far: is it time?


def said(text: str) -> Moment:
    return lambda out: text in out


def probe_down(depth_m: float) -> Moment:
    """A depth report from at least `depth_m` down has arrived: the cast is running."""
    reports = re.compile(r"← R-M t=\d+ depth (\d+\.\d+) m")
    return lambda out: any(float(d) >= depth_m for d in reports.findall(out))


async def _survey_interrupted_at(tmp_path: Path, *moments: Moment) -> tuple[int, str]:
    """A 2-station survey with a slow winch, sent a real SIGINT at each of `moments`
    in turn, as the run's output shows it; its exit status and plain output."""
    slow_winch = Pace("quick", 0.25, 300.0, 0.4, cast={"bottom_dwell_s": 5.0})
    out = io.StringIO()

    async def interrupt() -> None:
        for moment in moments:
            await until(lambda m=moment: m(out.getvalue()), what="the moment to interrupt")
            os.kill(os.getpid(), signal.SIGINT)

    interrupter = asyncio.create_task(interrupt())
    try:
        code = await run_simulation(
            SimOptions(
                stations=2,
                pace=slow_winch,
                firmware="manual",  # a cast that starts on arrival (no stick jog)
                db=tmp_path / "survey.db",
                live=False,
                out=out,
                handle_signals=True,
            )
        )
    finally:
        interrupter.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await interrupter
    return code, out.getvalue()


async def test_ctrl_c_mid_cast_brings_the_probe_home_and_prints_the_summary(
    tmp_path: Path,
) -> None:
    code, text = await _survey_interrupted_at(tmp_path, probe_down(0.5))
    assert code == 3, text
    assert "Ctrl-C: the daemon brings the probe home, then stops" in text
    assert "aborted: shutdown" in _row(text, "S1")
    assert "not reached" in _row(text, "S2")
    assert "interrupted: the daemon brought the probe home before stopping" in text
    assert "probe may be down" not in text
    assert "← R-F" in text
    assert [outcome for outcome, _, _ in _casts(tmp_path)] == ["aborted"]


async def test_ctrl_c_before_any_cast_claims_nothing_about_bringing_the_probe_home(
    tmp_path: Path,
) -> None:
    code, text = await _survey_interrupted_at(tmp_path, said("under way to S1"))
    assert code == 3, text
    assert "Ctrl-C: no cast running, the daemon stops" in text
    assert "interrupted before any cast: the probe never left home" in text
    assert "brought the probe home" not in text and "brings the probe home" not in text
    assert _casts(tmp_path) == []


async def test_a_second_ctrl_c_stops_at_once_and_the_summary_says_the_probe_may_be_down(
    tmp_path: Path,
) -> None:
    # The second once the first is heard (two pending at once would be one), with
    # the probe 1.5 m down: nearly 4 s from home at 0.4 m/s.
    code, text = await _survey_interrupted_at(
        tmp_path, probe_down(1.5), said("Ctrl-C: the daemon brings the probe home")
    )
    assert code == 130, text
    assert "second Ctrl-C: the daemon stops at once" in text
    assert "brought the probe home" not in text
    line = next(x for x in text.splitlines() if x.startswith("stopped at once"))
    depth = float(line.removeprefix("stopped at once: the probe may be down at ").split()[0])
    assert depth > 0.1
    assert "SURVEY INCOMPLETE: 0 of 1 castable station measured" in text
    assert text.endswith("(exit status 130)\n")
    # The counts say it too: a cast left unfinished, the probe still down.
    assert f"0 skipped, 1 unfinished; the probe left {depth:.2f} m down" in text


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
    # The stick's jog up jams at 0.5 m before M: the winch cannot vouch for home, so the
    # station is refused and held with R-L (the fault, for the ground station), never R-F.
    assert code == 4, text  # the survey halted: its own exit status
    assert "stranded: R-L x" in _row(text, "S1")
    assert "not reached" in _row(text, "S2")
    assert "giving up on the station with the probe last reported at 0.50 m" in text
    assert "← R-F" not in text  # never told to leave with the probe down
    assert "← R-L" in text and "the last at 0.50 m" in text
    assert "the probe stranded at 0.50 m: the daemon sent R-L" in text
    assert "interrupted" not in text
    assert ", 1 unfinished; the probe left 0.50 m down" in text
    # Withholding R-F from a probe that is down is the protocol kept.
    assert "R-F rightly withheld" in text
    assert text.endswith(
        "SURVEY HALTED: probe stranded at S1, fault reported to the autopilot: 0 of 1 "
        "castable station measured; the daemon kept the protocol (exit status 4)\n"
    )


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
            await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
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
            await asyncio.wait_for(daemon_task, WAIT_S)
            loop.remove_reader(pi_end.master_fd)
            loop.remove_reader(laptop_end.master_fd)
    text = out.getvalue()
    assert code == 0, text
    assert f"simulate-autopilot on {laptop_end.path} at 9600 baud" in text
    assert "measured" in _row(text, "S1")
    assert "skipped: too shallow" in _row(text, "S2")
    assert "data stored" not in text  # the journal is on the other machine
    assert daemon.snapshot().casts_completed == 1


# ---------------------------------------------------------------- the summary, without a run


def _one_cast_run(*, drop_at: float | None = None) -> Run:
    """A run whose autopilot saw S1 cast (deepest R-M 0.75 m, then R-F) and nothing else."""
    from cc_daemon.core.protocol import Ack, DepthReport, Finished
    from cc_daemon.sim.autopilot import AutopilotConfig, Phase

    mission = make_mission(2, 1)
    autopilot = Autopilot(mission, AutopilotConfig(boat_speed_m_s=300.0))
    now = 0.0
    while autopilot.phase is not Phase.REQUESTING:
        autopilot.poll(now)
        now += 0.5
    autopilot.on_frame(now, Ack(0))
    autopilot.on_frame(now + 0.5, DepthReport(0, 750))
    autopilot.on_frame(now + 1.5, Finished(0, 0))
    return Run(mission, autopilot, SimConsole(io.StringIO(), live=False), drop_at=drop_at)


def test_reached_is_the_journals_depth_not_the_deepest_report_that_arrived() -> None:
    from cc_daemon.sim.summary import JournalCast

    run = _one_cast_run()
    stalled = JournalCast(1, 2.69, 1.0, "aborted", "winch fault: stall at 1.00 m")
    summary = build_summary(run, casts=[stalled], daemon_exit=0, db_path=None, log_path=None)
    s1 = summary.stations[0]
    assert s1.reached_depth_m == 1.0
    assert s1.verdict == "aborted: stall at 1.00 m"
    assert (
        "S1: the journal says the probe reached 1.00 m; the deepest R-M that arrived said 0.75 m"
        in summary.notes
    )
    # Without a journal record (simulate-autopilot), what the autopilot heard.
    remote = build_summary(run, casts=None, daemon_exit=None, db_path=None, log_path=None)
    assert remote.stations[0].reached_depth_m == 0.75
    assert remote.notes == []
    assert remote.stations[1].reached_depth_m is None  # not reached


def test_a_drop_link_at_beyond_the_end_of_the_run_is_reported() -> None:
    run = _one_cast_run(drop_at=500.0)
    summary = build_summary(run, casts=None, daemon_exit=0, db_path=None, log_path=None)
    [note] = [n for n in summary.notes if n.startswith("cable never pulled")]
    assert note.startswith("cable never pulled: the run ended at ")
    assert note.endswith(" s, before --drop-link-at 500")
    assert build_summary(_one_cast_run(), casts=None, daemon_exit=0, db_path=None, log_path=None)


def test_the_reconnect_grace_follows_the_daemons_backoff(tmp_path: Path) -> None:
    base = Settings.model_validate({"serial": {"reconnect_max_s": 9.0}})
    options = SimOptions(db=tmp_path / "s.db", settings=base)
    settings = daemon_settings(options, tmp_path / "tty")
    assert autopilot_config(options, settings).outage_grace_s == 10.0
    default = daemon_settings(SimOptions(db=tmp_path / "s.db"), tmp_path / "tty")
    assert autopilot_config(options, default).outage_grace_s == 6.0


def _simulate_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    parser.add_argument("--db", type=Path)
    add_simulate_arguments(parser)
    return parser


def test_drop_link_for_zero_is_refused_not_turned_into_three_seconds(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        _simulate_parser().parse_args(["--drop-link-at", "5", "--drop-link-for", "0"])
    assert "--drop-link-for" in capsys.readouterr().err
    args = _simulate_parser().parse_args(["--drop-link-at", "5", "--drop-link-for", "0.5"])
    assert options_from_args(args, None).drop_link_for == 0.5
    args.drop_link_for = 0.0  # however it got there
    with pytest.raises(ValueError, match="--drop-link-for 0"):
        options_from_args(args, None)


def test_a_mission_that_cannot_be_laid_out_is_a_usage_error(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(mission_module, "_MIN_SPACING_M", 10_000.0)  # nowhere is far enough
    with pytest.raises(ValueError, match="station 2 cannot be placed"):
        make_mission(3, 1)
    args = _simulate_parser().parse_args(["--stations", "3", "--db", str(tmp_path / "s.db")])
    args.realtime = False
    assert run_from_args(args) == EXIT_USAGE
    assert "cc-daemon --simulate: stations=3, seed=1: station 2 cannot be placed" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "s.db").exists()


# ---------------------------------------------------------------- the daemon's log


def test_the_log_tap_never_raises_into_the_daemon_and_queues_events(tmp_path: Path) -> None:
    clock = iter([1.0, 2.0])
    with (tmp_path / "log").open("w", encoding="utf-8") as file:
        tap = LogTap(file, lambda: next(clock))
        tap.write(json.dumps({"level": "info", "event": "cast started", "cast_id": 1}) + "\n")
        tap.write('{"level": "debug", "event": "frame"}\n{"level": "warn')  # debug: file only
        tap.write('ing", "event": "corrupt frames received"}\nnot json\n')
    tap.write('{"level": "error", "event": "after the file closed"}\n')  # no raise
    tap.flush()
    assert tap.write_errors == 2
    events = tap.drain()
    assert [(at, e["event"]) for at, e in events] == [
        (1.0, "cast started"),
        (2.0, "corrupt frames received"),
    ]
    assert tap.drain() == []
    assert LogTap.describe(events[0][1]) == "daemon: cast started  cast_id=1"
    lines = (tmp_path / "log").read_text().splitlines()
    assert len(lines) == 4


def test_the_log_tap_has_no_finaliser_to_trip_over_a_closed_file(tmp_path: Path) -> None:
    """Under `python -X dev`, an io stream's finaliser flushing a closed file is reported."""
    script = (
        "import gc, sys\n"
        "from cc_daemon.sim.logtap import LogTap\n"
        f"file = open({str(tmp_path / 'log')!r}, 'w')\n"
        "tap = LogTap(file, lambda: 0.0)\n"
        "tap.write('{}\\n')\n"
        "file.close()\n"
        "del tap\n"
        "gc.collect()\n"
    )
    done = subprocess.run(
        [sys.executable, "-X", "dev", "-c", script],
        capture_output=True,
        text=True,
        timeout=30,
        cwd=REPO,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""


# ---------------------------------------------------------------- output cut short


def test_a_reader_that_leaves_mid_cast_does_not_strand_the_probe(tmp_path: Path) -> None:
    """`cc-daemon --simulate | head`: the output stops, the survey does not."""
    db = tmp_path / "pipe.db"
    env = {
        **os.environ,
        "CC_DAEMON_CAST__TARGET_DEPTH_M": "2.0",  # a short cast
        "PYTHONDEVMODE": "1",
    }
    with subprocess.Popen(
        [sys.executable, "-m", "cc_daemon", "--simulate", "--stations", "1", "--db", str(db)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        cwd=REPO,
    ) as proc:
        assert proc.stdout is not None
        assert proc.stderr is not None
        try:
            for raw in proc.stdout:
                if b"cast started" in raw:
                    break  # the probe is going down: the reader leaves
            proc.stdout.close()
            err = proc.stderr.read().decode()
            code = proc.wait(timeout=START_S + WAIT_S)
        finally:
            if proc.poll() is None:
                proc.kill()
    assert code == 0, err
    assert "Traceback" not in err
    assert "Exception ignored" not in err
    log = db.with_suffix(".log").read_text()
    assert "probe may be down" not in log
    assert "cast finished: probe home, R-F sent" in log
    # The daemon's own events: dev mode also has asyncio log each callback a busy
    # machine made slow ("Executing <Task ...> took 0.379 seconds").
    events = [e["event"] for e in map(json.loads, log.splitlines()) if e["logger"] != "asyncio"]
    assert events[-1] == "cc-daemon stopped"
    with JournalReader(db) as reader:
        assert [c.outcome for c in reader.casts()] == ["completed"]


def gpio_mock_pace(cast: dict[str, float], finish_margin_s: float) -> tuple[Settings, Pace]:
    """The GPIO winch on mock pins, and a quick pace with this cast: a winch fault's
    survey in a few seconds."""
    gpio_mock = Settings.model_validate(
        # The loop watchdog at its longest: a loaded machine's pause is not the fault
        # under test (the stall it would report would change the survey's verdict).
        {"winch": {"backend": "gpio", "gpio": {"pin_factory": "mock", "loop_watchdog_s": 5.0}}}
    )
    quick = Pace(
        "quick",
        frame_period_s=0.25,
        boat_speed_m_s=300.0,
        winch_speed_m_s=1.0,
        cast=cast,
        finish_margin_s=finish_margin_s,
    )
    return gpio_mock, quick


async def test_a_switch_stuck_closed_on_the_mock_drum_halts_the_survey_honestly(
    tmp_path: Path,
) -> None:
    gpio_mock, quick = gpio_mock_pace(
        {"bottom_dwell_s": 0.5, "max_duration_s": 3.0, "target_depth_m": 2.0}, 3.0
    )
    code, text, _ = await _simulate(
        tmp_path, stations=2, pace=quick, settings=gpio_mock, winch_fault="switch-stuck"
    )
    assert code == 4, text  # main's stranded survey: SURVEY HALTED, exit status 4
    assert "--winch-fault switch-stuck" in text.splitlines()[0]
    assert "witnesses disagree" in text
    assert "stranded: R-L x" in _row(text, "S1")
    assert "← R-F" not in text
    assert "SURVEY HALTED: probe stranded at S1, fault reported to the autopilot" in text
    [(outcome, _planned, reached)] = _casts(tmp_path)
    assert outcome == "unfinished" and reached is not None and reached < 1.0


def test_a_winch_fault_needs_the_mock_drum(capsys: pytest.CaptureFixture[str]) -> None:
    from cc_daemon.cli.app import main

    assert main(["--simulate", "--winch-fault", "snag"]) == 2
    assert "--winch-fault snag: applies only with --winch gpio-mock" in capsys.readouterr().err
