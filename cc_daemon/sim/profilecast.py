"""A simulated cast as a series of sonde readings, without the daemon: for the profiles'
tests and benchmarks, which need many casts of known water in little time.

This module owns a cast's legs in time (waiting at the surface, an optional soak,
the descent in one go or in steps, the bottom dwell, the ascent) and reading
`water.SondeModel` along them every `period_s`, from a random phase. The winch is
the simulated one: its line runs at a constant speed on each leg. It returns the
readings as `science.profiles.process.Series` and never reads a clock or a journal.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

import numpy as np

from cc_daemon.science.profiles.process import Series
from cc_daemon.sim.water import SondeModel, WaterColumn

SLANT_DEG = 8.0  # the simulated line's drift (water.SondeModel's default)


@dataclass(frozen=True, slots=True)
class CastShape:
    """The legs of a cast: line speeds (m/s of line), depths (m of probe depth), times (s)."""

    depth_m: float = 5.0
    descent_m_s: float = 0.125  # the plan's limit, or the winch's speed
    line_speed_m_s: float = 0.25  # the winch's own: the ascent, a stepped cast's moves
    bottom_dwell_s: float = 10.0
    wait_s: float = 2.0
    soak_s: float = 0.0
    soak_depth_m: float = 0.5
    step_m: float | None = None  # a stepped cast: a level every step_m
    dwell_s: float = 6.0  # at each level of a stepped cast
    period_s: float = 1.0


@dataclass(slots=True)
class _Legs:
    """The line out as a function of time: (time, line out) corners, joined linearly."""

    corners: list[tuple[float, float]] = field(default_factory=lambda: [(0.0, 0.0)])
    soak: tuple[float, float] = (0.0, 0.0)

    def hold(self, seconds: float) -> None:
        t, line = self.corners[-1]
        self.corners.append((t + seconds, line))

    def move(self, line_m: float, speed_m_s: float) -> None:
        t, line = self.corners[-1]
        self.corners.append((t + abs(line_m - line) / speed_m_s, line_m))

    def line_at(self, t: float) -> float:
        times = [c[0] for c in self.corners]
        return float(np.interp(t, times, [c[1] for c in self.corners]))


def _legs(shape: CastShape) -> _Legs:
    line_per_depth = 1 / math.cos(math.radians(SLANT_DEG))
    legs = _Legs()
    legs.hold(shape.wait_s)
    if shape.soak_s > 0:
        legs.move(shape.soak_depth_m * line_per_depth, shape.line_speed_m_s)
        legs.hold(shape.soak_s)
        legs.soak = (0.0, legs.corners[-1][0])
    if shape.step_m is not None:
        level = shape.step_m
        while level < shape.depth_m - 0.01:
            legs.move(level * line_per_depth, shape.line_speed_m_s)
            legs.hold(shape.dwell_s)
            level += shape.step_m
    legs.move(shape.depth_m * line_per_depth, shape.descent_m_s)
    legs.hold(shape.bottom_dwell_s if shape.step_m is None else shape.dwell_s)
    legs.move(0.0, shape.line_speed_m_s)
    legs.hold(shape.wait_s)
    return legs


def simulated_cast(shape: CastShape, water: WaterColumn | None = None, *, seed: int = 0) -> Series:
    """The readings of one cast of `shape` in `water`, the seed fixing noise and phase."""
    model = SondeModel(water or WaterColumn(), slant_deg=SLANT_DEG, rng=random.Random(seed))
    legs = _legs(shape)
    end = legs.corners[-1][0]
    t = random.Random(seed + 1).uniform(0.0, shape.period_s)
    times: list[float] = []
    lines: list[float] = []
    readings: list[dict[str, float]] = []
    while t <= end:
        line = legs.line_at(t)
        readings.append(model.read(line, t))
        times.append(t)
        lines.append(line)
        t += shape.period_s
    time_s = np.array(times)
    soak_start, soak_end = legs.soak
    return Series(
        time_s=time_s,
        depth_m=np.array([r["depth"] for r in readings]),
        line_out_m=np.array(lines),
        values={name: np.array([r[name] for r in readings]) for name in readings[0]},
        soaking=(time_s > soak_start) & (time_s <= soak_end),
    )
