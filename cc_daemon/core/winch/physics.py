"""Line-speed physics of a simulated winch, as a pure model of time.

Position is a function of time: a motion starts at a depth and a time and runs
at a constant line speed towards its end point, which is the target, or where
an injected fault stops it (a stall on the way down, a jam short of home on the
way up). Nothing here sleeps; ask it about any `now`.
"""

from __future__ import annotations

from dataclasses import dataclass

from cc_daemon.core.winch.status import APPROACH_FRACTION, WinchStatus

HOME_TOLERANCE_M = 0.005  # the limit switch closes within 5 mm of the top
JAM_DEPTH_M = 0.5  # with fail_home, an ascent jams this far below home


@dataclass(slots=True)
class _Motion:
    start_depth: float
    start_time: float
    end_depth: float
    end_time: float
    fault: str | None  # the fault raised when the motion ends, if it ends short


class LinePhysics:
    def __init__(
        self,
        *,
        speed_m_s: float,
        max_line_m: float,
        stall_at_m: float | None = None,
        fail_home: bool = False,
    ) -> None:
        if speed_m_s <= 0:
            raise ValueError("speed_m_s must be > 0")
        self.speed_m_s = speed_m_s
        self.max_line_m = max_line_m
        self.stall_at_m = stall_at_m
        self.fail_home = fail_home
        self._depth = 0.0  # depth when stopped
        self._motion: _Motion | None = None
        self._fault: str | None = None

    def command(
        self,
        now: float,
        target_m: float,
        *,
        slow: bool = False,
        max_speed_m_s: float | None = None,
    ) -> None:
        """Start moving from wherever the probe is now towards `target_m`; `slow`: at
        the approach speed (`APPROACH_FRACTION` of the line speed) the whole way;
        `max_speed_m_s`: no faster than it, and no slower than the approach speed."""
        depth = self.depth(now)
        self._settle(now)
        target = min(max(target_m, 0.0), self.max_line_m)
        end, fault = target, None
        if target > depth and self.stall_at_m is not None and depth <= self.stall_at_m < target:
            end, fault = self.stall_at_m, f"stall at {self.stall_at_m:.2f} m (line snagged)"
        elif target < depth and self.fail_home and target < JAM_DEPTH_M:
            end = min(depth, JAM_DEPTH_M)
            fault = f"home not reached: line jammed at {end:.2f} m"
        self._fault = None
        approach = self.speed_m_s * APPROACH_FRACTION
        speed = approach if slow else self.speed_m_s
        if max_speed_m_s is not None:
            speed = max(min(speed, max_speed_m_s), min(approach, speed))
        self._motion = _Motion(depth, now, end, now + abs(end - depth) / speed, fault)

    def stop(self, now: float) -> None:
        self._depth = self.depth(now)
        self._settle(now)
        self._motion = None

    def depth(self, now: float) -> float:
        motion = self._motion
        if motion is None:
            return self._depth
        if now >= motion.end_time:
            return motion.end_depth
        fraction = (now - motion.start_time) / (motion.end_time - motion.start_time)
        return motion.start_depth + (motion.end_depth - motion.start_depth) * fraction

    def arrival_time(self, now: float) -> float | None:
        """When the current motion ends (possibly already: not yet observed by
        `status`), or None if there is no motion."""
        motion = self._motion
        return None if motion is None else motion.end_time

    def status(self, now: float) -> WinchStatus:
        self._settle(now)
        depth = self.depth(now)
        return WinchStatus(
            depth_m=depth,
            moving=self._motion is not None,
            at_home=depth <= HOME_TOLERANCE_M,
            fault=self._fault,
        )

    def _settle(self, now: float) -> None:
        """Retire a motion that has ended, raising its fault if it ended short."""
        motion = self._motion
        if motion is not None and now >= motion.end_time:
            self._depth = motion.end_depth
            self._fault = motion.fault
            self._motion = None
