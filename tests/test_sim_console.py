"""The simulator's console: plain lines, the live view's pieces, the summary."""

from __future__ import annotations

import io
import os
from pathlib import Path

from cc_daemon.core.protocol import (
    Ack,
    CorruptFrame,
    DepthReport,
    ErrorKind,
    Finished,
    ProbePosition,
    ProbePositionRequest,
    StartMeasuring,
    Telemetry,
)
from cc_daemon.sim.autopilot import Violation, ViolationKind
from cc_daemon.sim.console import (
    SimConsole,
    StationRow,
    Summary,
    ViewState,
    depth_bar,
    describe_frame,
    render_to_text,
    summary_lines,
    summary_table,
)
from cc_daemon.sim.mission import make_mission


def test_frames_are_described_in_one_readable_line() -> None:
    t = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
    assert describe_frame(t) == (
        "P-T t=72 40.4506308 -3.7260579 alt 702.385 m  sonar 8.219 m 100 %"
    )
    assert describe_frame(StartMeasuring(*t)).startswith("P-M t=72 40.4506308")
    assert describe_frame(ProbePositionRequest(72)) == "P-S t=72"
    assert describe_frame(Ack(72)) == "R-O t=72"
    assert describe_frame(DepthReport(72, 15820)) == "R-M t=72 depth 15.820 m"
    assert describe_frame(Finished(72, 0)) == "R-F t=72 depth 0.000 m"
    assert describe_frame(ProbePosition(72, 4776)) == "R-P t=72 depth 4.776 m"


def test_the_depth_bar_scales_to_the_bottom_and_marks_the_plan() -> None:
    bar = depth_bar(2.0, 3.0, 4.0, width=40).plain
    assert len(bar) == 41
    assert bar.count("█") == 20  # half way to the bottom
    assert bar.index("┃") == 30  # the plan at three quarters
    assert bar.endswith("▓")
    home = depth_bar(0.0, None, None, width=10).plain
    assert home == "·" * 10 + " "
    # A probe below the bottom (a daemon bug) still draws, the bar grows to fit.
    assert depth_bar(5.0, None, 4.0, width=10).plain.count("█") == 10


def _plain() -> tuple[SimConsole, io.StringIO]:
    out = io.StringIO()
    return SimConsole(out, live=False), out


def test_plain_mode_prints_the_mission_then_time_stamped_lines() -> None:
    console, out = _plain()
    assert not console.live
    console.start(make_mission(3, 1), "cc-daemon --simulate: test")
    console.event(2.94, "S1: on station")
    console.frame_out(3.0, StartMeasuring(3, -37260579, 404506308, 702385, 3180, 95))
    console.frame_in(3.01, Ack(3))
    console.frame_in(4.0, DepthReport(4, 1000))
    console.frame_in(4.5, ProbePosition(4, 1498))
    console.frame_in(7.6, Finished(7, 0))
    error = CorruptFrame(ErrorKind.BAD_CHECKSUM, bytes.fromhex("524d"), "x")
    console.corrupt_in(8.0, error)
    console.stop()
    lines = out.getvalue().splitlines()
    assert lines[0] == "cc-daemon --simulate: test"
    assert lines[1].startswith("  S1 at 40.45")
    assert "(a shoal: too shallow to cast)" in lines[2]
    assert lines[4:] == [
        "    2.9 s  S1: on station",
        "    4.0 s  ← R-M t=4 depth 1.000 m",
        "    7.6 s  ← R-F t=7 depth 0.000 m",
        "    8.0 s  corrupt frame from the daemon: bad_checksum 52 4D",
    ]
    assert "\x1b[" not in out.getvalue()  # no terminal codes in a pipe


def test_the_live_view_shows_progress_probe_and_frames() -> None:
    console, _ = _plain()
    console.start(make_mission(3, 1), "x")
    console.frame_out(3.0, ProbePositionRequest(3))
    console.frame_in(3.01, ProbePosition(3, 1498))
    console.update(
        ViewState(
            elapsed_s=5.0,
            station_number=1,
            station_count=3,
            autopilot_phase="casting",
            water_depth_m=3.18,
            probe_depth_m=2.0,
            planned_depth_m=2.69,
            daemon_phase="descending",
            daemon_link_up=True,
            frames_out=11,
            frames_in=3,
            progress=[("S1", "▸"), ("S2", "·"), ("S3", "·")],
        )
    )
    text = render_to_text(lambda c: c.print(console.render()), width=100)
    assert "5.0 s" in text
    assert "stations done 0/3" in text
    assert "link up" in text
    assert "S1 ▸  S2 ·  S3 ·" in text
    assert "daemon: descending" in text
    assert "█" in text
    assert "planned 2.69 m ┃   bottom 3.18 m ▓" in text
    assert "frames → 11  ← 3" in text
    assert "→ P-S t=3" in text
    assert "← R-P t=3 depth 1.498 m" in text
    console.update(ViewState(cable_plugged=False))
    assert "cable pulled" in render_to_text(lambda c: c.print(console.render()))


def _summary(**changes: object) -> Summary:
    rows = [
        StationRow(1, 40.450836, -3.723396, 3.18, 2.69, 2.69, 7.4, 7, "measured", True),
        StationRow(2, 40.452224, -3.720368, 0.6, 0.11, 0.0, 0.0, 0, "skipped: too shallow", True),
    ]
    summary = Summary(
        seed=1,
        elapsed_s=14.2,
        stations=rows,
        frames_to_daemon=30,
        frames_from_daemon=12,
        corrupt_from_daemon=0,
        corrupt_at_daemon=0,
        bits_flipped_out=0,
        bits_flipped_in=0,
        m_sent=2,
        link_drops=0,
        daemon_port_losses=0,
        casts_completed=1,
        casts_aborted=0,
        casts_skipped=1,
        violations=[],
        db_path=Path("/tmp/x/simulate.db"),
        log_path=Path("/tmp/x/simulate.log"),
        exit_code=0,
        measured=1,
        castable=1,
    )
    for key, value in changes.items():
        setattr(summary, key, value)
    return summary


def test_the_summary_table_has_a_row_per_station() -> None:
    text = render_to_text(lambda c: c.print(summary_table(_summary())), width=110)
    header = next(line for line in text.splitlines() if "station" in line)
    for column in ("position", "water", "planned", "reached", "cast", "R-M", "verdict"):
        assert column in header
    s1 = next(line for line in text.splitlines() if line.strip().startswith("S1"))
    assert s1.split() == [
        "S1", "40.45084", "N", "3.72340", "W", "3.18", "m", "2.69", "m", "2.69", "m",
        "7.4", "s", "7", "measured",
    ]  # fmt: skip
    s2 = next(line for line in text.splitlines() if line.strip().startswith("S2"))
    assert "0.11 m" in s2
    assert "skipped: too shallow" in s2


def test_on_a_narrow_terminal_the_position_takes_two_lines_and_the_verdict_shows() -> None:
    text = render_to_text(lambda c: c.print(summary_table(_summary(), narrow=True)), width=80)
    lines = text.splitlines()
    s1 = next(i for i, line in enumerate(lines) if line.strip().startswith("S1"))
    assert "40.45084 N" in lines[s1]
    assert "measured" in lines[s1]
    assert "3.72340 W" in lines[s1 + 1]
    assert all(len(line) <= 80 for line in lines)


def test_the_summary_totals_say_where_the_data_is_and_how_to_export_it() -> None:
    lines = summary_lines(_summary())
    assert lines[0] == "frames: 30 to the daemon (2 M), 12 from it; run took 14.2 s"
    assert lines[1] == "corrupt frames: 0 from the daemon, 0 rejected by the daemon"
    assert "daemon: 1 cast(s) completed, 0 aborted, 1 skipped" in lines
    assert "protocol violations: 0" in lines
    assert "data stored in /tmp/x/simulate.db; next, as typed here:" in lines
    assert any(
        line.endswith(
            " -m cc_daemon export --db /tmp/x/simulate.db --format csv -o /tmp/x/simulate.csv"
        )
        for line in lines
    )
    # The profiles' products, named in a block of their own before the log and the verdict.
    block = lines.index("profiles a limnologist can publish:")
    assert lines[block + 1].endswith(
        " -m cc_daemon profiles --db /tmp/x/simulate.db -o /tmp/x/simulate-profiles"
    )
    assert "stations.csv and stations.geojson (thermocline" in lines[block + 2]
    assert lines[block + 3] == "the lake floor from this run's soundings:"
    assert lines[block + 4].endswith(
        " -m cc_daemon map --db /tmp/x/simulate.db -o /tmp/x/simulate-map"
    )
    assert lines[block + 6].startswith("daemon log (JSON lines):")
    assert lines[-1] == (
        "SURVEY OK: 1 of 1 castable station measured; the daemon kept the protocol (exit status 0)"
    )


def test_the_summary_lists_problems_and_groups_excused_ones() -> None:
    excused = [
        Violation(7.0 + i, ViolationKind.NO_PROBE_ANSWER, "no R-P", 1, "the cable was unplugged")
        for i in range(3)
    ]
    real = Violation(9.0, ViolationKind.FINISHED_NOT_HOME, "R-F at 1.5 m", 1)
    summary = _summary(
        violations=[*excused, real],
        exit_code=1,
        protocol_kept=False,
        link_drops=1,
        daemon_port_losses=1,
        bits_flipped_out=5,
        bits_flipped_in=2,
        corrupt_at_daemon=4,
    )
    lines = summary_lines(summary)
    assert "protocol violations: 1 (+3 explained by injected faults)" in lines
    assert "      9.0 s  S1 R-F with the probe down: R-F at 1.5 m" in lines
    assert "  excused: 3 x S not answered (the cable was unplugged)" in lines
    assert any("cable pulled 1 time(s); the daemon lost its port 1 time(s)" in x for x in lines)
    assert any("injected: 5 bits flipped towards the daemon, 2 towards" in x for x in lines)
    assert lines[-1] == (
        "SURVEY OK: 1 of 1 castable station measured; PROTOCOL VIOLATED (1 violation) "
        "(exit status 1)"
    )


def test_print_summary_writes_table_and_totals() -> None:
    console, out = _plain()
    console.print_summary(
        _summary(interrupted=True, notes=["a note"], daemon_exit=0, probe_depth_m=0.0)
    )
    text = out.getvalue()
    assert "Survey summary" in text
    assert "skipped: too shallow" in text
    assert "a note" in text
    assert "interrupted: the daemon brought the probe home before stopping" in text


def _ending(**changes: object) -> list[str]:
    lines = summary_lines(_summary(**changes))
    return [x for x in lines if x.startswith(("interrupted", "stopped at once"))]


def test_the_summary_says_how_the_run_ended_for_the_probe_and_only_what_it_knows() -> None:
    assert _ending(daemon_exit=0, probe_depth_m=0.0) == []
    assert _ending(interrupted=True, daemon_exit=0, probe_depth_m=0.0) == [
        "interrupted: the daemon brought the probe home before stopping"
    ]
    # Two Ctrl-C: the daemon stopped the winch where it was.
    assert _ending(interrupted=True, daemon_exit=130, probe_depth_m=2.78) == [
        "stopped at once: the probe may be down at 2.78 m"
    ]
    # Not interrupted, but the daemon still had to be stopped at once (a jammed winch).
    assert _ending(daemon_exit=130, probe_depth_m=0.5) == [
        "stopped at once: the probe may be down at 0.50 m"
    ]
    assert _ending(interrupted=True, daemon_exit=0, probe_depth_m=1.2) == [
        "interrupted: the daemon stopped with the probe at 1.20 m"
    ]
    # simulate-autopilot: the daemon is on the other end of a cable.
    remote = _ending(interrupted=True, remote=True, probe_depth_m=1.5)
    assert remote == [
        "interrupted: the simulated autopilot stopped; the daemon on the other end carries "
        "on as it sees fit; it last reported the probe at 1.50 m"
    ]
    assert "home" not in remote[0]


def test_a_closed_pipe_stops_the_output_not_the_caller() -> None:
    """`cc-daemon --simulate | head`: rich would raise SystemExit(1) mid-run."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader left
    with os.fdopen(write_end, "w", encoding="utf-8") as out:
        console = SimConsole(out, live=False)
        assert console.output_lost is None
        console.start(make_mission(3, 1), "cc-daemon --simulate: test")
        assert isinstance(console.output_lost, BrokenPipeError)
        console.event(1.0, "more")
        console.frame_in(4.0, DepthReport(4, 1000))
        console.print_summary(_summary())
        console.stop()
        # The descriptor now leads to /dev/null: closing (flushing) the stream succeeds.


def test_the_live_view_survives_a_terminal_that_went_away() -> None:
    read_end, write_end = os.pipe()
    os.close(read_end)
    with os.fdopen(write_end, "w", encoding="utf-8") as out:
        console = SimConsole(out, live=True)
        console.start(make_mission(3, 1), "x")
        console.event(1.0, "an event")
        console.stop()
        console.print_summary(_summary())
        assert console.output_lost is not None


def test_a_probe_left_where_the_winch_could_only_estimate_is_said_as_an_estimate() -> None:
    stranded = {"stranded_at": 1, "exit_code": 4, "casts_unfinished": 1, "probe_depth_m": 1.272}
    lines = summary_lines(_summary(**stranded, probe_range_m=(0.566, 1.979)))
    estimate = "about 1.27 m (an estimate: between 0.57 and 1.98 m)"
    assert any(line.endswith(f"the probe left {estimate} down") for line in lines), lines
    assert f"the probe stranded at {estimate}: the daemon sent R-L" in "\n".join(lines)
    measured = "\n".join(summary_lines(_summary(**stranded)))
    assert "the probe left 1.27 m down" in measured and "the probe stranded at 1.27 m:" in measured
