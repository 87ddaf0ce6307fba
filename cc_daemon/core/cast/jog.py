"""Manual probe jog from the RC stick (`P-U` / `P-D`): a dead-man's handle.

The firmware (7ab06076 on) sends `U` or `D` about once a second for as long as
the safety pilot holds the probe stick. `D` pays the probe out and `U` hauls
it in, at the winch's own speed, while frames keep coming; the motion stops on
its own `hold_s` after the last frame, at `max_line_m`, at home, and on any
winch fault. A jog never sends `R-F`, never starts a cast and sends no reply.
Whether a stick frame may jog at all (not during a cast) is the shell's call.

Pure: fed the stick, the time and the winch's status; returns actions
(`MoveWinch`, `HaltWinch`) and records (`JogStarted`, `JogStopped`) for the
shell to carry out and journal. It never touches the winch itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from cc_daemon.core.winch.status import WinchStatus


class Stick(StrEnum):
    UP = "up"
    DOWN = "down"


@dataclass(frozen=True, slots=True)
class MoveWinch:
    depth_m: float


@dataclass(frozen=True, slots=True)
class HaltWinch:
    reason: str


@dataclass(frozen=True, slots=True)
class JogStarted:
    stick: Stick
    depth_m: float


@dataclass(frozen=True, slots=True)
class JogStopped:
    stick: Stick
    reason: str
    from_depth_m: float
    depth_m: float
    duration_s: float


JogAction = MoveWinch | HaltWinch | JogStarted | JogStopped

# Why a jog stopped (journaled as is).
RELEASED = "stick released"
AT_HOME = "probe home"
LINE_END = "end of the line"
REVERSED = "stick reversed"
_EPS_M = 0.005


class Jog:
    def __init__(self, hold_s: float, max_line_m: float) -> None:
        if hold_s <= 0 or max_line_m <= 0:
            raise ValueError("hold_s and max_line_m must be > 0")
        self.hold_s = hold_s
        self.max_line_m = max_line_m
        self.stick: Stick | None = None  # the running jog's direction
        self._last_frame = 0.0
        self._started_at = 0.0
        self._from_m = 0.0

    @property
    def active(self) -> bool:
        return self.stick is not None

    def next_deadline(self) -> float | None:
        return None if self.stick is None else self._last_frame + self.hold_s

    def frame(self, stick: Stick, now: float, status: WinchStatus) -> list[JogAction]:
        """A stick frame arrived (no cast running: the shell checked)."""
        out: list[JogAction] = []
        if self.stick is stick:
            self._last_frame = now
            return out
        if self.stick is not None:
            self._stop(out, now, status, REVERSED)
        if stick is Stick.UP and status.at_home:
            return out  # nothing to haul in
        if stick is Stick.DOWN and status.depth_m >= self.max_line_m - _EPS_M:
            return out  # no line left to pay out
        self.stick = stick
        self._last_frame = self._started_at = now
        self._from_m = status.depth_m
        out.append(JogStarted(stick, status.depth_m))
        out.append(MoveWinch(self.max_line_m if stick is Stick.DOWN else 0.0))
        return out

    def step(self, now: float, status: WinchStatus) -> list[JogAction]:
        """Check the running jog against the time and the winch."""
        out: list[JogAction] = []
        if self.stick is None:
            return out
        if status.fault is not None:
            self._stop(out, now, status, f"winch fault: {status.fault}")
        elif self.stick is Stick.UP and status.at_home:
            self._stop(out, now, status, AT_HOME)
        elif self.stick is Stick.DOWN and status.depth_m >= self.max_line_m - _EPS_M:
            self._stop(out, now, status, LINE_END)
        elif now - self._last_frame >= self.hold_s:
            self._stop(out, now, status, RELEASED)
        return out

    def cancel(self, now: float, status: WinchStatus, reason: str) -> list[JogAction]:
        """Stop a running jog for the shell's reason (a station, a shutdown)."""
        out: list[JogAction] = []
        if self.stick is not None:
            self._stop(out, now, status, reason)
        return out

    def _stop(self, out: list[JogAction], now: float, status: WinchStatus, reason: str) -> None:
        assert self.stick is not None
        out.append(HaltWinch(f"jog {self.stick}: {reason}"))
        out.append(
            JogStopped(
                self.stick,
                reason,
                self._from_m,
                status.depth_m,
                round(now - self._started_at, 3),
            )
        )
        self.stick = None
