"""The pure machines behind the firmware's ways: the RC stick's jog, R-F repeats
and the lost-M watch, on fake time and a fake winch status."""

from __future__ import annotations

import pytest

from cc_daemon.core.cast.jog import (
    AT_HOME,
    LINE_END,
    RELEASED,
    REVERSED,
    HaltWinch,
    Jog,
    JogStarted,
    JogStopped,
    MoveWinch,
    Stick,
)
from cc_daemon.core.cast.lost_start import LostStartWatch
from cc_daemon.core.cast.rf_repeat import RfRepeater
from cc_daemon.core.protocol import Finished
from cc_daemon.core.winch.status import WinchStatus

HOME = WinchStatus(0.0, False, True, None)


def at(depth: float, moving: bool = True, fault: str | None = None) -> WinchStatus:
    return WinchStatus(depth, moving, depth <= 0.0, fault)


def stopped(actions: list[object]) -> JogStopped:
    [stop] = [a for a in actions if isinstance(a, JogStopped)]
    assert any(isinstance(a, HaltWinch) for a in actions)
    return stop


# ---------------------------------------------------------------- the jog


def test_down_pays_out_while_frames_come_and_stops_after_the_hold() -> None:
    jog = Jog(hold_s=2.5, max_line_m=20.0)
    assert jog.frame(Stick.DOWN, 0.0, HOME) == [JogStarted(Stick.DOWN, 0.0), MoveWinch(20.0)]
    for t in (1.0, 2.0, 3.0):  # the stick held: one frame a second, nothing new to do
        assert jog.frame(Stick.DOWN, t, at(t * 0.25)) == []
        assert jog.step(t + 0.5, at(t * 0.25)) == []
    assert jog.step(5.4, at(1.3)) == []  # 2.4 s after the last frame
    stop = stopped(jog.step(5.5, at(1.35)))  # 2.5 s: the dead-man stop
    assert (stop.reason, stop.from_depth_m, stop.depth_m, stop.duration_s) == (
        RELEASED,
        0.0,
        1.35,
        5.5,
    )
    assert not jog.active and jog.step(9.0, at(1.35, moving=False)) == []


def test_up_hauls_in_and_stops_at_home() -> None:
    jog = Jog(hold_s=2.5, max_line_m=20.0)
    assert jog.frame(Stick.UP, 0.0, at(3.0, moving=False)) == [
        JogStarted(Stick.UP, 3.0),
        MoveWinch(0.0),
    ]
    assert jog.step(1.0, at(2.0)) == []
    assert stopped(jog.step(1.9, HOME)).reason == AT_HOME


def test_up_at_home_does_nothing() -> None:
    jog = Jog(hold_s=2.5, max_line_m=20.0)
    assert jog.frame(Stick.UP, 0.0, HOME) == []
    assert not jog.active


def test_down_stops_at_the_end_of_the_line_and_will_not_start_there() -> None:
    jog = Jog(hold_s=2.5, max_line_m=4.0)
    jog.frame(Stick.DOWN, 0.0, HOME)
    assert stopped(jog.step(1.0, at(4.0, moving=False))).reason == LINE_END
    assert jog.frame(Stick.DOWN, 1.5, at(4.0, moving=False)) == []


def test_a_winch_fault_stops_the_jog() -> None:
    jog = Jog(hold_s=2.5, max_line_m=20.0)
    jog.frame(Stick.DOWN, 0.0, HOME)
    stop = stopped(jog.step(0.8, at(0.2, moving=False, fault="stall")))
    assert stop.reason == "winch fault: stall"


def test_reversing_the_stick_stops_then_starts_the_other_way() -> None:
    jog = Jog(hold_s=2.5, max_line_m=20.0)
    jog.frame(Stick.DOWN, 0.0, HOME)
    actions = jog.frame(Stick.UP, 2.0, at(0.5))
    assert stopped(actions[:2]).reason == REVERSED
    assert actions[2:] == [JogStarted(Stick.UP, 0.5), MoveWinch(0.0)]
    assert jog.stick is Stick.UP


def test_cancel_stops_a_running_jog_only() -> None:
    jog = Jog(hold_s=2.5, max_line_m=20.0)
    assert jog.cancel(0.0, HOME, "shutdown") == []
    jog.frame(Stick.DOWN, 0.0, HOME)
    assert stopped(jog.cancel(1.0, at(0.25), "start-measuring")).reason == "start-measuring"
    assert jog.next_deadline() is None


def test_the_deadline_is_the_hold_after_the_last_frame() -> None:
    jog = Jog(hold_s=2.5, max_line_m=20.0)
    jog.frame(Stick.DOWN, 10.0, HOME)
    jog.frame(Stick.DOWN, 11.0, at(0.25))
    assert jog.next_deadline() == 13.5


# ---------------------------------------------------------------- R-F repeats

RF = Finished(22, 0)


def test_rf_is_repeated_after_silence_up_to_the_limit() -> None:
    rf = RfRepeater(after_s=2.5, repeats=3)
    rf.sent(RF, 100.0)
    assert rf.due(102.4) is None
    assert rf.due(102.5) == RF and rf.sent_again == 1
    assert rf.due(104.9) is None  # the silence is counted from the last R-F
    assert rf.due(105.0) == RF and rf.sent_again == 2
    assert rf.due(107.5) == RF and rf.sent_again == 3
    assert rf.due(200.0) is None and not rf.waiting


def test_any_frame_ends_the_repeats() -> None:
    rf = RfRepeater(after_s=2.5, repeats=3)
    rf.sent(RF, 0.0)
    assert rf.due(2.5) == RF
    rf.frame_received()
    assert rf.due(10.0) is None and rf.next_deadline() is None


def test_zero_repeats_sends_nothing_again() -> None:
    rf = RfRepeater(after_s=2.5, repeats=0)
    rf.sent(RF, 0.0)
    assert rf.due(2.5) is None and not rf.waiting


def test_a_new_rf_restarts_the_count() -> None:
    rf = RfRepeater(after_s=1.0, repeats=1)
    rf.sent(RF, 0.0)
    assert rf.due(1.0) == RF and rf.due(5.0) is None
    rf.sent(Finished(40, 0), 10.0)
    assert rf.due(11.0) == Finished(40, 0)


# ---------------------------------------------------------------- lost M


def test_t_stopping_after_corrupt_frames_with_no_cast_is_a_lost_m_once() -> None:
    watch = LostStartWatch(silence_s=3.0)
    watch.heard(10.0)
    watch.corrupt(10.0)
    assert watch.check(13.0, cast_running=False) is None  # 3 s is not more than 3 s
    lost = watch.check(13.1, cast_running=False)
    assert lost is not None and lost.corrupt_frames == 1 and lost.silent_for_s == 3.1
    assert watch.suspected == lost
    assert watch.check(20.0, cast_running=False) is None  # said once per silence
    watch.heard(21.0)  # T again: the autopilot was not waiting after all
    assert watch.suspected is None


@pytest.mark.parametrize("cast_running", [True, False])
def test_silence_alone_or_during_a_cast_is_no_lost_m(cast_running: bool) -> None:
    watch = LostStartWatch(silence_s=3.0)
    watch.heard(0.0)
    if cast_running:
        watch.corrupt(0.5)
    assert watch.check(60.0, cast_running=cast_running) is None


def test_corrupt_frames_before_the_last_t_do_not_count() -> None:
    watch = LostStartWatch(silence_s=3.0)
    watch.corrupt(4.0)
    watch.heard(5.0)
    assert watch.check(30.0, cast_running=False) is None


def test_before_any_t_there_is_nothing_to_miss() -> None:
    watch = LostStartWatch(silence_s=3.0)
    watch.corrupt(1.0)
    assert watch.check(30.0, cast_running=False) is None


def test_a_silence_while_our_port_is_down_is_no_lost_m() -> None:
    # --corrupt 0.02 --drop-link-at 6: corrupt frames, then the cable goes.
    watch = LostStartWatch(silence_s=3.0)
    watch.heard(10.0)
    watch.corrupt(10.5)
    watch.link(False, 11.0)
    assert watch.check(20.0, cast_running=False) is None  # the cable is quiet, not the boat
    watch.link(True, 20.0)
    assert watch.check(22.0, cast_running=False) is None  # the silence starts over
    watch.heard(22.5)  # T again: nothing was lost
    assert watch.check(40.0, cast_running=False) is None


def test_a_silence_that_outlasts_the_reconnection_is_still_a_lost_m() -> None:
    watch = LostStartWatch(silence_s=3.0)
    watch.heard(10.0)
    watch.corrupt(10.5)
    watch.link(False, 11.0)
    watch.link(True, 15.0)
    lost = watch.check(18.5, cast_running=False)
    assert lost is not None and lost.silent_for_s == 3.5


def test_corrupt_frames_that_keep_coming_are_a_noisy_line_not_a_waiting_boat() -> None:
    # --corrupt: two frames in a row spoilt; the autopilot still sends, so no lost M.
    watch = LostStartWatch(silence_s=3.0)
    watch.heard(10.0)
    watch.corrupt(11.1)
    watch.corrupt(12.2)
    assert watch.check(13.4, cast_running=False) is None
    watch.heard(13.3)
    # After M the firmware sends nothing: the silence after the last corrupt frame.
    watch.corrupt(14.4)
    assert watch.check(17.4, cast_running=False) is None
    lost = watch.check(17.5, cast_running=False)
    assert lost is not None and lost.silent_for_s == 3.1 and lost.corrupt_frames == 1
