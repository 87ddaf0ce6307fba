"""The simulated autopilot's state machine, on fake time (plain numbers)."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from cc_daemon.core.protocol import (
    Ack,
    CorruptFrame,
    DepthReport,
    ErrorKind,
    FaultReport,
    Finished,
    Message,
    ProbePosition,
    ProbePositionRequest,
    StartMeasuring,
    Telemetry,
)
from cc_daemon.sim.autopilot import BITS_FLIPPED, Autopilot, AutopilotConfig, Phase, ViolationKind
from cc_daemon.sim.mission import Mission, make_mission

FAST = AutopilotConfig(frame_period_s=1.0, boat_speed_m_s=100.0)


def _mission() -> Mission:
    return make_mission(3, seed=1)  # S2 is the shoal with this seed


def _run_until(ap: Autopilot, phase: Phase, start: float = 0.0, limit: float = 100.0) -> float:
    """Poll once a second until `phase`; return the time reached."""
    now = start
    while ap.phase is not phase:
        ap.poll(now)
        if ap.phase is phase:
            break
        now += 1.0
        assert now < limit, f"never reached {phase}"
    return now


def _frames(ap: Autopilot, start: float, seconds: int) -> list[Message]:
    out: list[Message] = []
    for i in range(seconds):
        out += ap.poll(start + i)
    return out


def test_the_mission_fixture_has_its_shoal_at_s2() -> None:
    assert [s.too_shallow for s in _mission().stations] == [False, True, False]


def test_cruising_sends_telemetry_along_the_transit_once_a_period() -> None:
    ap = Autopilot(_mission(), AutopilotConfig(frame_period_s=1.0, boat_speed_m_s=10.0))
    frames = [ap.poll(t / 4) for t in range(40)]  # polled four times a period
    sent = [f for batch in frames for f in batch]
    assert len(sent) == 10
    assert all(isinstance(f, Telemetry) for f in sent)
    assert [f.timestamp_s for f in sent] == list(range(10))
    start = _mission().start.e7
    first = sent[0]
    assert isinstance(first, Telemetry)
    assert (first.lon_e7, first.lat_e7) == start
    assert abs(first.alt_m - 702.385) < 0.05
    lats = [f.lat_e7 for f in sent if isinstance(f, Telemetry)]
    assert len(set(lats)) == 10  # moving


def test_no_burst_of_frames_after_a_long_pause() -> None:
    ap = Autopilot(_mission(), FAST)
    assert len(ap.poll(0.0)) == 1
    assert len(ap.poll(30.0)) == 1
    assert ap.poll(30.5) == []
    assert ap.next_deadline == 31.0


def test_resends_m_every_period_until_r_o_then_telemetry_and_s() -> None:
    ap = Autopilot(_mission(), FAST)
    t = _run_until(ap, Phase.REQUESTING)
    requests = _frames(ap, t + 1, 4)
    assert all(isinstance(f, StartMeasuring) for f in requests)
    assert ap.logs[0].m_sent == 5  # the poll that arrived sent the first
    station = _mission().stations[0]
    m = requests[0]
    assert isinstance(m, StartMeasuring)
    assert (m.lon_e7, m.lat_e7) == station.point.e7
    assert abs(m.sonar_distance_m - station.water_depth_m) <= 0.05
    assert m.sonar_confidence_pct >= 92
    # The daemon was silent for four seconds: each unanswered second is a violation.
    assert [v.kind for v in ap.violations] == [ViolationKind.NO_ACK] * 2

    ap.on_frame(t + 4.2, Ack(0))
    assert ap.phase is Phase.CASTING
    kinds = []
    for i in range(6):
        ap.on_frame(t + 4.5 + i, DepthReport(0, 100 * i))
        for frame in ap.poll(t + 5 + i):
            kinds.append(type(frame))
            if isinstance(frame, ProbePositionRequest):
                ap.on_frame(t + 5.01 + i, ProbePosition(0, 100 * i))
    assert kinds == [Telemetry, Telemetry, ProbePositionRequest] * 2
    assert ap.logs[0].s_sent == 2


def test_keeps_resending_m_during_the_cast_when_configured() -> None:
    config = AutopilotConfig(frame_period_s=1.0, boat_speed_m_s=100.0, resend_m_during_cast=True)
    ap = Autopilot(_mission(), config)
    t = _run_until(ap, Phase.REQUESTING)
    ap.poll(t + 1)
    ap.on_frame(t + 1.01, Ack(0))
    kinds = []
    for i in range(6):
        batch = ap.poll(t + 2 + i)
        kinds += [type(f) for f in batch]
        ap.on_frame(
            t + 2.01 + i, Ack(0) if isinstance(batch[0], StartMeasuring) else ProbePosition(0, 500)
        )
        ap.on_frame(t + 2.02 + i, DepthReport(0, 500))
    assert kinds == [StartMeasuring, StartMeasuring, ProbePositionRequest] * 2
    assert ap.violations == []


def test_holds_position_during_the_cast_and_leaves_only_after_r_f() -> None:
    mission = _mission()
    ap = Autopilot(mission, FAST)
    t = _run_until(ap, Phase.REQUESTING)
    ap.poll(t + 1)
    ap.on_frame(t + 1.1, Ack(0))
    station = mission.stations[0].point.e7
    for i in range(60):  # a long cast: a minute of reports
        now = t + 2 + i
        for frame in ap.poll(now):
            if isinstance(frame, Telemetry):
                assert (frame.lon_e7, frame.lat_e7) == station
            else:
                ap.on_frame(now + 0.01, ProbePosition(0, 1000))
        ap.on_frame(now + 0.5, DepthReport(0, min(i * 100, 3000)))
        assert ap.phase is Phase.CASTING
    ap.on_frame(t + 62.2, Finished(0, 0))
    assert ap.phase is Phase.CRUISING
    moved = [f for f in _frames(ap, t + 63, 3) if isinstance(f, Telemetry)]
    assert moved
    assert all((f.lon_e7, f.lat_e7) != station for f in moved)
    log = ap.logs[0]
    assert log.reports == 60
    assert log.max_depth_m == 3.0
    assert log.cast_duration_s == pytest.approx(61.1)
    assert log.verdict == "measured"
    assert ap.violations == []


def _at_cast(config: AutopilotConfig = FAST) -> tuple[Autopilot, float]:
    ap = Autopilot(_mission(), config)
    t = _run_until(ap, Phase.REQUESTING)
    ap.poll(t + 1)
    ap.on_frame(t + 1.01, Ack(0))
    return ap, t + 1.01


def test_flags_r_f_with_a_non_zero_depth() -> None:
    ap, t = _at_cast()
    ap.on_frame(t + 1, DepthReport(0, 1500))
    ap.on_frame(t + 1.5, Finished(0, 1500))
    assert [v.kind for v in ap.violations] == [ViolationKind.FINISHED_NOT_HOME]
    assert "1.500 m" in ap.violations[0].detail
    assert ap.logs[0].verdict == "FAILED: R-F with the probe down"
    assert ap.problems == ap.violations


def test_flags_a_gap_of_more_than_three_seconds_and_retries_m() -> None:
    ap, t = _at_cast()
    ap.on_frame(t + 1, DepthReport(0, 500))
    ap.poll(t + 3.5)
    ap.poll(t + 3.99)
    assert ap.violations == []  # 2.99 s: not yet
    frames = ap.poll(t + 4.1)
    assert [v.kind for v in ap.violations] == [ViolationKind.REPORT_GAP]
    assert ap.violations[0].station == 1
    assert not ap.violations[0].excused
    # The firmware still has the station selected: M until the daemon answers.
    later = frames + _frames(ap, t + 5, 2)
    assert any(isinstance(f, StartMeasuring) for f in later)
    ap.on_frame(t + 7, Finished(0, 0))  # the repeated R-F for a done station
    assert ap.phase is Phase.CRUISING
    assert len(ap.violations) == 1  # flagged once per gap


def test_a_retry_answered_by_r_o_alone_keeps_resending_m_until_r_f() -> None:
    """A finished cast answers M with R-O then R-F: if that R-F is lost, M again."""
    ap, t = _at_cast()
    ap.on_frame(t + 1, DepthReport(0, 0))  # the last report; its R-F will be lost
    ap.poll(t + 4.1)  # the gap: M from now on
    ap.on_frame(t + 4.2, Ack(0))  # the R-O to a resent M; the R-F behind it is lost
    later = _frames(ap, t + 5, 3)
    assert any(isinstance(f, StartMeasuring) for f in later)
    ap.on_frame(t + 8.2, Finished(0, 0))
    assert ap.phase is Phase.CRUISING


def test_a_steady_report_stream_is_not_a_gap() -> None:
    ap, t = _at_cast()
    for i in range(30):
        ap.on_frame(t + i + 0.9, DepthReport(0, 100 * i))
        for frame in ap.poll(t + i + 1):
            if isinstance(frame, ProbePositionRequest):
                ap.on_frame(t + i + 1.001, ProbePosition(0, 100 * i))
    assert ap.violations == []


def test_flags_corrupt_frames_unless_a_bit_was_flipped_on_the_way() -> None:
    error = CorruptFrame(ErrorKind.BAD_CHECKSUM, bytes.fromhex("524d00483dcc01f1"), "checksum")
    ap, t = _at_cast()
    ap.on_corrupt(t, error)
    assert [v.kind for v in ap.problems] == [ViolationKind.CORRUPT_FRAME]
    assert "52 4D 00 48 3D CC 01 F1" in ap.violations[0].detail

    noisy, t = _at_cast()
    noisy.bits_flipped(t + 0.5, inbound=True)
    noisy.on_corrupt(t + 0.5, error)
    assert noisy.problems == []
    assert noisy.violations[0].excused_by == BITS_FLIPPED
    # A flip on our own frames cannot spoil the daemon's.
    noisy.on_frame(t + 1.0, DepthReport(0, 300))
    noisy.bits_flipped(t + 5.0, inbound=False)
    noisy.on_corrupt(t + 5.0, error)
    assert [v.kind for v in noisy.problems] == [ViolationKind.CORRUPT_FRAME]


def test_a_corrupt_frame_is_excused_by_a_flip_since_the_last_thing_heard() -> None:
    error = CorruptFrame(ErrorKind.BAD_CHECKSUM, bytes.fromhex("524f004800ea"), "checksum")
    ap, t = _at_cast()
    ap.bits_flipped(t + 1.0, inbound=True)
    ap.on_frame(t + 4.0, DepthReport(0, 300))
    ap.on_corrupt(t + 7.0, error)  # the flip was before the last good frame: not this one
    assert [v.kind for v in ap.problems] == [ViolationKind.CORRUPT_FRAME]
    # A mangled frame is reported when the bytes after it arrive, maybe much later.
    ap.bits_flipped(t + 8.0, inbound=True)
    ap.on_corrupt(t + 15.0, error)
    assert ap.violations[-1].excused_by == BITS_FLIPPED


def test_noise_far_from_a_silent_daemon_does_not_excuse_it() -> None:
    """Injected noise excuses only what it could have caused: the violations near a flip."""
    ap = Autopilot(_mission(), FAST)
    t = _run_until(ap, Phase.REQUESTING)
    ap.bits_flipped(t + 0.5, inbound=False)  # the one M it mangled
    for i in range(1, 61):  # a minute of M, and not a word from the daemon
        ap.poll(t + i)
    no_ack = [v for v in ap.violations if v.kind is ViolationKind.NO_ACK]
    assert len(no_ack) >= 20
    assert no_ack[0].excused_by == BITS_FLIPPED
    assert all(not v.excused for v in no_ack[1:])
    assert len(ap.problems) == len(no_ack) - 1


@pytest.mark.parametrize("firmware", ["ucm-2023", "manual"])
def test_the_2023_firmwares_only_m_lost_to_noise_excuses_the_missing_r_f(firmware: str) -> None:
    # The 2023 firmware sends M once: mangled on the way, no daemon can end the
    # station. The manual's autopilot resends M, so its silent daemon has no excuse.
    config = AutopilotConfig(boat_speed_m_s=100.0, finish_timeout_s=20.0, firmware=firmware)  # type: ignore[arg-type]
    ap = Autopilot(_mission(), config)
    t = _run_until(ap, Phase.REQUESTING)
    ap.bits_flipped(t + 0.5, inbound=False)  # the M it sent is mangled
    for i in range(1, 40):
        ap.poll(t + i)  # the daemon never heard an M: not a word from it
    [no_finish] = [v for v in ap.violations if v.kind is ViolationKind.NO_FINISH]
    if firmware == "ucm-2023":
        assert no_finish.excused_by is not None and "its only M was lost" in no_finish.excused_by
        assert ap.problems == []
    else:
        assert not no_finish.excused and no_finish in ap.problems


def test_noise_excuses_a_lost_answer_and_a_report_gap_around_it() -> None:
    ap, t = _at_cast()
    ap.on_frame(t + 0.5, DepthReport(0, 300))
    ap.bits_flipped(t + 1.5, inbound=True)  # the reports stop: their bytes were mangled
    for i in range(1, 6):
        ap.poll(t + i)
    gap = [v for v in ap.violations if v.kind is ViolationKind.REPORT_GAP]
    assert len(gap) == 1
    assert gap[0].excused_by == BITS_FLIPPED
    ap.on_frame(t + 6.5, DepthReport(0, 300))
    for i in range(7, 12):
        ap.poll(t + i)  # silence again, and no flip since 1.5 s
    gap = [v for v in ap.violations if v.kind is ViolationKind.REPORT_GAP]
    assert [v.excused for v in gap] == [True, False]


def test_flags_s_not_answered_within_a_second() -> None:
    ap, t = _at_cast()
    frames: list[Message] = []
    for i in range(1, 4):
        ap.on_frame(t + i - 0.5, DepthReport(0, 300))
        frames += ap.poll(t + i)
    assert isinstance(frames[-1], ProbePositionRequest)
    ap.on_frame(t + 3.5, DepthReport(0, 300))
    ap.poll(t + 3.9)
    assert ap.violations == []
    ap.poll(t + 4.05)
    assert [v.kind for v in ap.violations] == [ViolationKind.NO_PROBE_ANSWER]


def test_flags_a_depth_below_the_bottom_or_beyond_the_line() -> None:
    ap, t = _at_cast()
    bottom = _mission().stations[0].water_depth_m
    ap.on_frame(t + 0.5, DepthReport(0, round((bottom + 0.04) * 1000)))  # within tolerance
    assert ap.violations == []
    ap.on_frame(t + 1, DepthReport(0, round((bottom + 0.2) * 1000)))
    assert [v.kind for v in ap.violations] == [ViolationKind.DEPTH_OUT_OF_RANGE]
    ap.on_frame(t + 2, DepthReport(0, 65535))
    assert "beyond 20.0 m of line" in ap.violations[-1].detail


def test_flags_frames_that_make_no_sense_now() -> None:
    ap = Autopilot(_mission(), FAST)
    ap.poll(0)
    ap.on_frame(0.1, DepthReport(0, 100))
    ap.on_frame(0.2, Finished(0, 0))
    ap.on_frame(0.3, Ack(0))
    ap.on_frame(0.4, ProbePosition(0, 0))
    ap.on_frame(0.5, Telemetry(0, 0, 0, 0, 0, 0))
    assert [v.kind for v in ap.violations] == [ViolationKind.UNEXPECTED_FRAME] * 5


def test_late_answers_just_after_leaving_are_not_news() -> None:
    ap, t = _at_cast()
    ap.on_frame(t + 0.5, DepthReport(0, 100))
    ap.on_frame(t + 1.0, Finished(0, 0))
    ap.on_frame(t + 1.1, Ack(0))
    ap.on_frame(t + 1.2, Finished(0, 0))
    assert ap.violations == []


def test_a_refusal_at_the_shoal_is_expected_and_at_a_deep_station_is_not() -> None:
    ap, t = _at_cast()
    ap.on_frame(t + 0.01, Finished(0, 0))  # refused S1, which is deep
    assert [v.kind for v in ap.violations] == [ViolationKind.UNEXPECTED_SKIP]
    assert ap.logs[0].verdict == "FAILED: deep station not cast"

    relaxed = AutopilotConfig(boat_speed_m_s=100.0, check_plan=False)
    ap, t = _at_cast(relaxed)
    ap.on_frame(t + 0.01, Finished(0, 0))
    assert ap.violations == []
    assert ap.logs[0].verdict == "skipped"


@pytest.mark.parametrize("firmware", ["manual", "ucm-2023"])
def test_r_l_is_recorded_and_the_station_held_until_r_f(firmware: str) -> None:
    config = AutopilotConfig(boat_speed_m_s=100.0, firmware=firmware)  # type: ignore[arg-type]
    ap, t = _at_cast(config)
    ap.on_frame(t + 1, DepthReport(0, 1500))
    for i in range(2, 12):  # stranded: R-L every second, far past the report gap
        ap.on_frame(t + i, FaultReport(0, 1480))
        for frame in ap.poll(t + i + 0.5):
            if isinstance(frame, ProbePositionRequest):
                ap.on_frame(t + i + 0.51, ProbePosition(0, 1480))
    log = ap.logs[0]
    assert (log.fault_reports, log.fault_depth_m, ap.error_last) == (10, 1.48, 76)
    assert ap.phase is Phase.CASTING and ap.index == 0  # still at the station
    assert log.verdict == "stranded: R-L x10, no R-F"
    assert ap.violations == []  # R-L is the daemon keeping the protocol
    ap.on_frame(t + 13, Finished(0, 0))  # hauled in by hand: released
    assert ap.error_last == 0 and log.finished_at is not None and ap.index == 1


def test_gives_up_on_a_station_without_r_f_but_does_not_leave() -> None:
    config = AutopilotConfig(boat_speed_m_s=100.0, finish_timeout_s=20.0)
    ap, t = _at_cast(config)
    arrived = ap.logs[0].arrived_at
    assert arrived is not None
    for i in range(30):
        ap.on_frame(t + i, DepthReport(0, 2000))  # stranded: the same depth, no R-F
        for frame in ap.poll(t + i + 0.5):
            if isinstance(frame, ProbePositionRequest):
                ap.on_frame(t + i + 0.51, ProbePosition(0, 2000))
    assert ap.phase is Phase.DONE
    assert ap.finished
    assert [v.kind for v in ap.violations] == [ViolationKind.NO_FINISH]
    assert "2.00 m" in ap.violations[0].detail
    assert ap.logs[0].verdict == "no R-F"
    assert ap.logs[1].verdict == "not reached"
    assert not ap.survey_complete


def test_an_unplugged_cable_excuses_the_silence_it_causes() -> None:
    ap, t = _at_cast()
    ap.on_frame(t + 0.5, DepthReport(0, 300))
    ap.link_down(t + 1)
    for i in range(2, 6):
        ap.poll(t + i)
    ap.link_up(t + 6)
    ap.poll(t + 7)
    gap = [v for v in ap.violations if v.kind is ViolationKind.REPORT_GAP]
    assert len(gap) == 1
    assert gap[0].excused_by == "the cable was unplugged"
    assert ap.problems == []
    # Long after the replug, silence is the daemon's fault again.
    ap.on_frame(t + 20, DepthReport(0, 300))
    ap.poll(t + 24)
    assert [v.kind for v in ap.problems] == [ViolationKind.REPORT_GAP]


def test_finish_reports_a_station_left_waiting() -> None:
    ap, t = _at_cast()
    ap.finish(t + 5, interrupted=True)
    assert ap.violations[0].kind is ViolationKind.NO_FINISH
    assert ap.violations[0].excused_by == "stopped by the operator"
    ap.finish(t + 6)
    assert len(ap.violations) == 1


@dataclass
class IdealDaemon:
    """What the protocol says a CC does, in a few lines: for a whole-mission run."""

    cast_s: int = 8
    casts: int = 0
    depth_m: float = 0.0
    cast_started: float | None = None
    done_at: dict[tuple[int, int], float] = field(default_factory=dict)

    def answer(self, now: float, frame: Message) -> list[Message]:
        if isinstance(frame, ProbePositionRequest):
            return [ProbePosition(0, round(self.depth_m * 1000))]
        if not isinstance(frame, StartMeasuring):
            return []
        if self.cast_started is not None:
            return [Ack(0)]
        here = (frame.lon_e7, frame.lat_e7)
        if here in self.done_at:
            return [Ack(0), Finished(0, 0)]
        if frame.sonar_distance_m - 0.5 < 0.3:
            self.done_at[here] = now
            return [Ack(0), Finished(0, 0)]
        self.casts += 1
        self.cast_started = now
        self._here = here
        return [Ack(0)]

    def tick(self, now: float) -> list[Message]:
        if self.cast_started is None:
            return []
        elapsed = now - self.cast_started
        half = self.cast_s / 2
        self.depth_m = max(0.0, half - abs(elapsed - half)) * 0.5
        if elapsed >= self.cast_s:
            self.cast_started = None
            self.done_at[self._here] = now
            self.depth_m = 0.0
            return [Finished(0, 0)]
        return [DepthReport(0, round(self.depth_m * 1000))]


@pytest.mark.parametrize("resend", [False, True])
def test_a_whole_mission_against_a_well_behaved_daemon(resend: bool) -> None:
    config = AutopilotConfig(boat_speed_m_s=50.0, resend_m_during_cast=resend)
    ap = Autopilot(_mission(), config)
    cc = IdealDaemon()
    now = 0.0
    while ap.phase is not Phase.DONE and now < 200:
        for frame in ap.poll(now):
            for reply in cc.answer(now, frame):
                ap.on_frame(now + 0.001, reply)
        if now == int(now):
            for reply in cc.tick(now + 0.5):
                ap.on_frame(now + 0.5, reply)
        now += 0.5
    ap.finish(now)
    assert ap.violations == []
    assert ap.survey_complete
    assert cc.casts == 2  # one station, one cast, however often M came
    assert [log.verdict for log in ap.logs] == ["measured", "skipped: too shallow", "measured"]
    assert ap.logs[1].reports == 0
    assert all(log.reports >= 6 for log in (ap.logs[0], ap.logs[2]))
    assert 1.5 <= ap.logs[0].max_depth_m <= 2.0


def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError, match="frame_period_s"):
        AutopilotConfig(frame_period_s=0)
    with pytest.raises(ValueError, match="boat_speed_m_s"):
        AutopilotConfig(boat_speed_m_s=-1)
    with pytest.raises(ValueError, match="query_every"):
        AutopilotConfig(query_every=1)
    with pytest.raises(ValueError, match="noise_margin_s"):
        AutopilotConfig(noise_margin_s=-1)
    with pytest.raises(ValueError, match="outage_grace_s"):
        AutopilotConfig(outage_grace_s=-1)


def test_r_f_after_the_cable_returns_is_not_read_as_a_refusal() -> None:
    # --drop-link-at 5: R-O, the cable out, every R-M lost, the repeated R-F arrives.
    ap, t = _at_cast(AutopilotConfig(boat_speed_m_s=100.0, firmware="ucm-2023"))
    ap.link_down(t + 0.5)
    ap.link_up(t + 3.5)
    ap.on_frame(t + 8.0, Finished(0, 0))
    [skip] = [v for v in ap.violations if v.kind is ViolationKind.UNEXPECTED_SKIP]
    assert skip.excused_by == "the cable was unplugged"
    assert ap.problems == [] and ap.logs[0].verdict == "skipped"
    # Without the cable pulled, R-F at once at a deep station is still a refusal.
    ap, t = _at_cast(AutopilotConfig(boat_speed_m_s=100.0, firmware="ucm-2023"))
    ap.on_frame(t + 8.0, Finished(0, 0))
    assert [v.kind for v in ap.problems] == [ViolationKind.UNEXPECTED_SKIP]
