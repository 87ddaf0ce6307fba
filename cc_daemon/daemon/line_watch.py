"""The deployed firmware's ways, for the daemon: timestamp order, R-F repeats,
the RC stick's jog and the lost-`M` watch (docs/firmware.md).

This module owns the shell side of four pure machines (`cast.timestamps`,
`cast.rf_repeat`, `cast.jog`, `cast.lost_start`): it feeds them what the
daemon hears and the time, and carries out what they decide, through the
callables the daemon gives it (write a frame, command the winch, journal an
event, tell systemd). It never decides anything itself, never starts or
aborts a cast (the daemon does, on a `U` during a cast) and never sends a
reply to a stick frame.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence

import structlog

from cc_daemon.config import Settings
from cc_daemon.core.cast.jog import (
    HaltWinch,
    Jog,
    JogAction,
    JogStarted,
    JogStopped,
    MoveWinch,
    Stick,
)
from cc_daemon.core.cast.lost_start import LostStartWatch
from cc_daemon.core.cast.rf_repeat import RfRepeater
from cc_daemon.core.cast.timestamps import TimestampOrder
from cc_daemon.core.protocol import Finished, Message, Telemetry, encode
from cc_daemon.core.winch.status import WinchStatus
from cc_daemon.ground.clock import Clock, run_on_deadlines

_log = structlog.get_logger("cc_daemon.service")

# While a jog runs, `tick` also watches the winch (home, the line's end, a fault):
# then it is due this often. Otherwise it is due only at the machines' deadlines.
TICK_S = 0.1


class LineWatch:
    def __init__(
        self,
        settings: Settings,
        *,
        write: Callable[[bytes], bool],
        move_winch: Callable[[float], None],
        stop_winch: Callable[[str], None],
        winch_status: Callable[[], WinchStatus],
        journal_event: Callable[..., None],
        notify: Callable[[str], None],
    ) -> None:
        self.order = TimestampOrder(settings.serial.timestamp_order)
        self.rf = RfRepeater(settings.cast.rf_repeat_after_s, settings.cast.rf_repeats)
        self.lost = LostStartWatch()
        self.jog = Jog(settings.serial.jog_hold_s, settings.winch.max_line_m)
        self._write = write
        self._move = move_winch
        self._stop = stop_winch
        self._status = winch_status
        self._event = journal_event
        self._notify = notify
        self.rf_repeats_sent = 0
        # Set when something may bring a deadline nearer (an R-F out, a corrupt frame,
        # a jog): the daemon's watch then recomputes `next_deadline` at once.
        self.changed = asyncio.Event()

    # ------------------------------------------------------------ what we hear

    def heard(self, message: Message, now: float) -> int:
        """Any frame from the autopilot: returns its time in its real value."""
        self.rf.frame_received()  # it speaks again: it read our R-F
        # Any readable frame (T, S, the stick's U and D) says the autopilot is not
        # waiting on a lost M: after M the firmware sends nothing until R-F.
        if self.lost.suspected is not None:
            _log.info(
                "the autopilot speaks again: it was not waiting on a lost M",
                frame=message.frame,
            )
            self._notify("STATUS=frames from the autopilot again")
        self.lost.heard(now)
        if isinstance(message, Telemetry):
            decision = self.order.observe_telemetry(message.timestamp_s, now)
            if decision is not None:
                _log.info(
                    "autopilot timestamp byte order decided",
                    order=decision.order,
                    votes=decision.votes,
                    against=decision.against,
                    evidence=[f"{a:04X}->{b:04X} in {s} s" for a, b, s in decision.evidence],
                )
                self._event("timestamp_order", order=decision.order, votes=decision.votes)
        return self.order.decode(message.timestamp_s)

    def heard_fixes(self, fixes: Sequence[Telemetry], now: float) -> int:
        """A run of `T` frames read together: as `heard` for each at `now`; returns the
        time of the last. At one instant only the first can vote on the byte order
        (the others pair with it 0 s apart) and the last is the one remembered, so
        those two are heard; the others cannot change anything."""
        time = self.heard(fixes[0], now)
        return self.heard(fixes[-1], now) if len(fixes) > 1 else time

    def corrupt(self, now: float) -> None:
        self.lost.corrupt(now)
        self.changed.set()

    def link_changed(self, up: bool, now: float) -> None:
        self.lost.link(up, now)
        self.changed.set()

    def finished_sent(self, frame: Finished, now: float) -> None:
        self.rf.sent(frame, now)
        self.changed.set()

    def cast_ended(self, now: float) -> None:
        self.lost.heard(now)  # the silence of the cast was expected

    # ------------------------------------------------------------ the RC stick

    def stick(self, stick: Stick, now: float) -> None:
        """A stick frame with no cast running: jog."""
        self._carry_out(self.jog.frame(stick, now, self._status()), now)
        self.changed.set()

    def stop_jog(self, now: float, reason: str) -> None:
        if self.jog.active:  # no winch to ask before the daemon has made one
            self._carry_out(self.jog.cancel(now, self._status(), reason), now)

    def _carry_out(self, actions: list[JogAction], now: float) -> None:
        for action in actions:
            match action:
                case MoveWinch(depth_m=depth):
                    try:
                        self._move(depth)
                    except Exception as exc:
                        _log.error(
                            "jog: winch command failed", error=f"{type(exc).__name__}: {exc}"
                        )
                        self._carry_out(self.jog.cancel(now, self._status(), f"winch: {exc}"), now)
                case HaltWinch(reason=reason):
                    self._stop(reason)
                case JogStarted(stick=stick, depth_m=depth):
                    _log.info("jog started (RC stick)", stick=str(stick), depth_m=round(depth, 3))
                    self._event("jog_started", stick=str(stick), depth_m=round(depth, 3))
                case JogStopped():
                    detail = {
                        "stick": str(action.stick),
                        "reason": action.reason,
                        "from_depth_m": round(action.from_depth_m, 3),
                        "depth_m": round(action.depth_m, 3),
                        "duration_s": action.duration_s,
                    }
                    _log.info("jog stopped (RC stick)", **detail)
                    self._event("jog_stopped", **detail)

    # ------------------------------------------------------------ each tick

    def next_deadline(self, now: float, *, cast_running: bool) -> float | None:
        """When `tick` next has something to do; None: nothing until `changed` is set.

        Each deadline is the machine's own (an R-F repeat, the lost-M silence); a
        running jog adds `now + TICK_S`. Nothing is polled when nothing is due.
        """
        due = [
            deadline
            for deadline in (self.rf.next_deadline(), self.lost.next_deadline(cast_running))
            if deadline is not None
        ]
        if self.jog.active:
            due.append(now + TICK_S)
        return min(due, default=None)

    def tick(self, now: float, *, cast_running: bool) -> None:
        if self.jog.active:
            self._carry_out(self.jog.step(now, self._status()), now)
        again = self.rf.due(now)
        if again is not None:
            sent = self._write(encode(again))
            self.rf_repeats_sent += 1
            _log.warning("autopilot silent after R-F: R-F sent again", repeat=self.rf.sent_again)
            self._event("rf_repeated", repeat=self.rf.sent_again, sent=sent)
        lost = self.lost.check(now, cast_running=cast_running)
        if lost is not None:
            _log.error(
                "telemetry stopped after corrupt frames: the autopilot may be waiting "
                "for an answer to a start-measuring frame we could not read",
                silent_for_s=lost.silent_for_s,
                corrupt_frames=lost.corrupt_frames,
            )
            self._event(
                "start_measuring_lost",
                silent_for_s=lost.silent_for_s,
                corrupt_frames=lost.corrupt_frames,
            )
            self._notify(f"STATUS={self.lost_start_text()}")

    def lost_start_text(self) -> str | None:
        lost = self.lost.suspected
        if lost is None:
            return None
        return (
            f"autopilot silent after {lost.corrupt_frames} corrupt frame(s): "
            "a start-measuring frame may have been lost"
        )


async def watch_line(line: LineWatch, clock: Clock, cast_running: Callable[[], bool]) -> None:
    """The daemon's duty: the jog's dead-man stop, R-F repeats and the lost-M watch,
    asleep until the next deadline, or until something brings one nearer."""
    await run_on_deadlines(
        clock,
        line.changed,
        lambda now: line.tick(now, cast_running=cast_running()),
        lambda now: line.next_deadline(now, cast_running=cast_running()),
    )
