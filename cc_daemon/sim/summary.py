"""The end of a simulated run: the journal's casts, the per-station rows and the verdict.

This module owns reading this run's casts back from the journal (matched to
stations by position) and turning a finished `Run` into the `Summary` the
console prints, exit status included. It reads; it never changes the run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from cc_daemon.sim.autopilot import Violation, ViolationKind
from cc_daemon.sim.console import EXIT_PROBE_MAY_BE_DOWN, StationRow, Summary
from cc_daemon.sim.mission import (
    EARTH_RADIUS_M,
    MIN_CASTABLE_WATER_M,
    ORIGIN_LAT_DEG,
    ORIGIN_LON_DEG,
    SONAR_MAX_NOISE_M,
    Mission,
    Point,
)
from cc_daemon.store.stations import MATCH_RADIUS_M

if TYPE_CHECKING:
    from cc_daemon.sim.session import Run

EXIT_OK = 0
EXIT_FAILED = 1  # the protocol was broken, or the daemon failed
EXIT_SURVEY_INCOMPLETE = 3  # the protocol kept, but a castable station was not measured
EXIT_SURVEY_HALTED = 4  # the protocol kept: a probe stranded, its fault reported (R-L)
EXIT_STATUSES = (
    "Exit status: 0 the daemon kept the protocol and every castable station was measured; "
    "1 a protocol violation (or the daemon failed); 3 the protocol kept, but a castable "
    "station was not measured (a cast aborted or left unfinished, an interrupted run); "
    "4 the survey halted: the probe stranded at a station and the daemon reported the "
    f"fault (R-L) instead of R-F; {EXIT_PROBE_MAY_BE_DOWN} the daemon was stopped at once "
    "and the probe may be down; 2 bad usage."
)
REARM_HINT = (
    "hint: 'deep station not cast' right after R-O is what a daemon that finished a cast "
    "at this station less than cast.rearm_s ago (120 s by default) does: it answers M "
    "with R-F at once. Wait that long between runs, or use another --seed."
)


def _local(lat_deg: float, lon_deg: float) -> Point:
    north = math.radians(lat_deg - ORIGIN_LAT_DEG) * EARTH_RADIUS_M
    east = (
        math.radians(lon_deg - ORIGIN_LON_DEG)
        * EARTH_RADIUS_M
        * math.cos(math.radians(ORIGIN_LAT_DEG))
    )
    return Point(east, north)


@dataclass(frozen=True, slots=True)
class JournalCast:
    """What the summary needs from one journal cast record."""

    station: int
    planned_depth_m: float
    reached_depth_m: float | None
    outcome: str | None
    reason: str | None
    cast_id: int | None = None


def journal_casts(db: Path, mission: Mission, survey: int | None) -> list[JournalCast]:
    """This run's casts in the journal (its session's: another run writing the same file
    at the same time is not this one), each matched to its station by position."""
    from cc_daemon.store import JournalReader

    found: list[JournalCast] = []
    with JournalReader(db, survey=survey) as reader:
        for record in reader.casts():
            here = _local(record.lat_deg, record.lon_deg)
            nearest = min(mission.stations, key=lambda s: s.point.distance_to(here))
            if (
                nearest.point.distance_to(here) <= MATCH_RADIUS_M
            ):  # the journal's own rule (`store.stations`)
                found.append(
                    JournalCast(
                        nearest.number,
                        record.planned_depth_m,
                        record.reached_depth_m,
                        record.outcome,
                        record.reason,
                        record.id,
                    )
                )
    return found


def _withheld_rightly(violation: Violation, run: Run) -> Violation:
    """A missing R-F at a station where the daemon's winch failed is the protocol
    kept, not broken: R-F is for a probe that is home, and this one is not."""
    fault = run.faults.get(violation.station) if violation.station is not None else None
    if violation.kind is not ViolationKind.NO_FINISH or violation.excused:
        return violation
    if fault is None and violation.station is not None:
        log = run.autopilot.logs[violation.station - 1]
        if log.fault_reports:  # what the daemon said on the wire, here or remote
            return replace(violation, excused_by="the daemon reported the fault (R-L)")
    if fault is None:
        return violation
    return replace(violation, excused_by=f"the winch failed ({fault}): R-F rightly withheld")


def _shortest_plan_m() -> float:
    """The shallowest plan the default settings make at any castable mission station."""
    from cc_daemon.config import CastSettings

    cast = CastSettings()
    return min(
        cast.target_depth_m,
        MIN_CASTABLE_WATER_M - SONAR_MAX_NOISE_M - cast.bottom_clearance_m,
    )


def build_summary(
    run: Run,
    *,
    casts: list[JournalCast] | None,
    daemon_exit: int | None,
    db_path: Path | None,
    log_path: Path | None,
    notes: list[str] | None = None,
) -> Summary:
    ap = run.autopilot
    now = run.now()
    violations = [_withheld_rightly(v, run) for v in ap.violations]
    by_station: dict[int, list[JournalCast]] = {}
    for recorded_cast in casts or []:
        by_station.setdefault(recorded_cast.station, []).append(recorded_cast)
    rows: list[StationRow] = []
    extra_notes: list[str] = []
    for log in ap.logs:
        number = log.station.number
        recorded = by_station.get(number, [])
        if len(recorded) > 1:
            violations.append(
                Violation(
                    now,
                    ViolationKind.DUPLICATE_CAST,
                    f"the journal holds {len(recorded)} casts for one station",
                    number,
                )
            )
        planned = recorded[-1].planned_depth_m if recorded else run.plans.get(number)
        verdict = log.verdict
        problems_here = [v for v in violations if v.station == number and not v.excused]
        ok = not problems_here and log.finished_at is not None
        outcome = recorded[-1].outcome if recorded else None
        if ok and verdict.startswith("skipped") and outcome == "completed":
            # The journal holds the cast; its R-M were lost while the cable was out.
            verdict = "measured"
            extra_notes.append(
                f"S{number}: no R-M arrived (the cable was out) but the journal holds the "
                f"cast, completed"
            )
        elif ok and outcome == "aborted":
            reason = recorded[-1].reason or "no reason given"
            verdict = f"aborted: {reason.removeprefix('winch fault: ')}"
        elif ok and number in run.faults and log.reports:
            verdict = f"aborted: {run.faults[number]}"
        elif (
            ok
            and verdict == "measured"
            and run.daemon is None
            and ap.config.check_plan
            and log.max_depth_m < _shortest_plan_m() - ap.config.depth_tolerance_m
        ):
            # A remote daemon's abort looks like a cast on the wire; only its depth
            # tells: every castable station of the mission plans deeper than this.
            verdict = f"cut short at {log.max_depth_m:.2f} m (aborted?)"
        # How deep the probe went: the daemon's journal knows (its winch); the
        # deepest R-M that arrived can fall short (a lost report, a stall
        # between two reports, a cable pulled mid-cast).
        heard = log.max_depth_m if log.reports else (0.0 if log.finished_at is not None else None)
        journal_reached = recorded[-1].reached_depth_m if recorded else None
        reached = journal_reached if journal_reached is not None else heard
        if journal_reached is not None and abs(journal_reached - log.max_depth_m) > 0.05:
            said = (
                f"the deepest R-M that arrived said {log.max_depth_m:.2f} m"
                if log.reports
                else "no R-M arrived"
            )
            extra_notes.append(
                f"S{number}: the journal says the probe reached {journal_reached:.2f} m; {said}"
            )
        if len(recorded) > 1:
            ok = False
            verdict = f"FAILED: {len(recorded)} casts"
        lat, lon = log.station.point.lat_lon
        rows.append(
            StationRow(
                number=number,
                lat_deg=lat,
                lon_deg=lon,
                water_depth_m=log.station.water_depth_m,
                planned_depth_m=planned,
                reached_depth_m=reached,
                duration_s=log.cast_duration_s,
                reports=log.reports,
                verdict=verdict,
                ok=ok,
            )
        )
    for log in ap.logs:
        if log.stick_down or log.stick_up:
            extra_notes.append(
                f"S{log.station.number}: stick jog before the station: {log.stick_down} P-D "
                f"then {log.stick_up} P-U frames (no reply expected)"
            )
    if run.drop_at is not None and run.link_drops == 0:
        extra_notes.append(
            f"cable never pulled: the run ended at {now:.1f} s, "
            f"before --drop-link-at {run.drop_at:g}"
        )
    elif run.unplugged_at is not None:
        extra_notes.append(
            f"the run ended with the cable still out (pulled at {run.unplugged_at:.1f} s)"
        )
    status = run.status
    # Where the probe ended: the daemon's winch here, or what a remote daemon last said.
    probe_depth_m = status.probe_depth_m if status is not None else None
    winch = status.winch if status is not None else None
    probe_range_m = (
        (winch.depth_low_m, winch.depth_high_m)
        if winch is not None and winch.depth_low_m is not None and winch.depth_high_m is not None
        else None
    )
    if run.daemon is None:
        probe_depth_m, probe_range_m = ap.probe_depth_m, None
    problems = [v for v in violations if not v.excused]
    if run.daemon is None and any(v.kind is ViolationKind.UNEXPECTED_SKIP for v in problems):
        extra_notes.append(REARM_HINT)
    castable = [row for row in rows if not _shoal(run, row.number)]
    measured = sum(1 for row in castable if row.verdict == "measured")
    protocol_kept = not problems and daemon_exit in (None, 0, EXIT_PROBE_MAY_BE_DOWN)
    survey_ok = (
        measured == len(castable)
        and ap.survey_complete
        and not run.interrupts
        and all(row.ok for row in rows)
    )
    stranded_at = next(
        (log.station.number for log in ap.logs if log.fault_reports and not log.finished_at),
        None,
    )
    for log in ap.logs:
        if log.fault_reports:
            extra_notes.append(
                f"S{log.station.number}: {log.fault_reports} R-L (fault reported; the "
                f"firmware's error_last 76 for the ground station), the last at "
                f"{log.fault_depth_m:.2f} m"
            )
    if stranded_at is not None and protocol_kept:
        code = EXIT_SURVEY_HALTED
    elif daemon_exit == EXIT_PROBE_MAY_BE_DOWN:
        code = EXIT_PROBE_MAY_BE_DOWN
    elif not protocol_kept:
        code = EXIT_FAILED
    elif not survey_ok:
        code = EXIT_SURVEY_INCOMPLETE
    else:
        code = EXIT_OK
    outcomes = [c.outcome for c in casts or []]
    return Summary(
        seed=run.mission.seed,
        elapsed_s=now,
        stations=rows,
        frames_to_daemon=sum(len(p.sent) for p in run.ports),
        frames_from_daemon=sum(len(p.received) for p in run.ports),
        corrupt_from_daemon=sum(len(p.errors) for p in run.ports),
        corrupt_at_daemon=status.corrupt_frames if status else None,
        bits_flipped_out=run.flip_out.bits_flipped if run.flip_out else 0,
        bits_flipped_in=run.flip_in.bits_flipped if run.flip_in else 0,
        m_sent=sum(log.m_sent for log in ap.logs),
        link_drops=run.link_drops,
        daemon_port_losses=status.port_losses if status else None,
        casts_completed=status.casts_completed if status else None,
        casts_aborted=status.casts_aborted if status else None,
        casts_skipped=status.casts_skipped if status else None,
        casts_unfinished=outcomes.count("unfinished") if casts is not None else None,
        violations=violations,
        db_path=db_path,
        log_path=log_path,
        exit_code=code,
        interrupted=run.interrupts > 0,
        notes=[*(notes or []), *extra_notes],
        daemon_exit=daemon_exit,
        probe_depth_m=probe_depth_m,
        probe_range_m=probe_range_m,
        remote=run.daemon is None,
        protocol_kept=protocol_kept,
        survey_complete=survey_ok,
        measured=measured,
        castable=len(castable),
        first_cast_id=next(
            (c.cast_id for c in casts or [] if (c.reached_depth_m or 0.0) > 0.0), None
        ),
        stranded_at=stranded_at,
        probe_went_down=any(log.reports for log in ap.logs)
        or any((c.reached_depth_m or 0.0) > 0.0 for c in casts or []),
    )


def _shoal(run: Run, number: int) -> bool:
    return any(s.too_shallow for s in run.mission.stations if s.number == number)
