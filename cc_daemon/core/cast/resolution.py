"""What a cast can resolve: the descent speed and the stepped dwell its sensors need.

Pure arithmetic on the configuration (docs/profiles.md gives the figures behind it):
a survey wants profiles on bins of `bin_m`, each bin holding at least
`min_count` readings taken every `period_s`; each sensor answers with a
first-order lag of its response time. The parameters the cast must resolve
(`resolve`) set the limits:

- a continuous descent runs at no more than one bin per response time of the
  slowest of them, and no more than one bin per `min_count` readings:
  `bin_m / max(slowest response, min_count * period_s)`;
- a stepped cast dwells at each level at least three response times of the
  slowest of them (95 % of a step is seen after three).

The limits only ever slow a cast down: the winch never runs faster than its own
speed, and not slower than its approach speed (the slowest it is known to run
steadily), so a limit under that one is said, not obeyed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

# Three response times: a first-order sensor then shows 95 % of a step.
SETTLING_RESPONSES = 3.0


@dataclass(frozen=True, slots=True)
class Resolution:
    """The survey's wanted resolution and its sensors' response times (s, by name)."""

    bin_m: float
    min_count: int
    period_s: float
    response_s: Mapping[str, float] = field(default_factory=dict)
    resolve: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.bin_m <= 0 or self.period_s <= 0 or self.min_count < 1:
            raise ValueError("bin_m and period_s must be > 0, min_count >= 1")
        unknown = [name for name in self.resolve if name not in self.response_s]
        if unknown:
            raise ValueError(f"no response time for {', '.join(unknown)}")

    @property
    def slowest(self) -> tuple[str, float] | None:
        """The parameter to resolve with the longest response time, and that time."""
        timed = [(name, self.response_s[name]) for name in self.resolve]
        return max(timed, key=lambda pair: pair[1]) if timed else None

    @property
    def descent_limit_m_s(self) -> float:
        """The fastest continuous descent that resolves `bin_m` (m/s)."""
        slowest = self.slowest
        response = slowest[1] if slowest is not None else 0.0
        return self.bin_m / max(response, self.min_count * self.period_s)

    @property
    def dwell_s(self) -> float:
        """The shortest dwell of a stepped cast's level (s)."""
        slowest = self.slowest
        return SETTLING_RESPONSES * slowest[1] if slowest is not None else 0.0

    def descent_m_s(self, winch_m_s: float, floor_m_s: float) -> float:
        """The speed a winch running `winch_m_s`, and no slower than `floor_m_s`,
        descends at under the limit."""
        return max(min(winch_m_s, self.descent_limit_m_s), min(floor_m_s, winch_m_s))

    def lags_m(self, speed_m_s: float) -> dict[str, float]:
        """How far behind the probe each lagging sensor reads at `speed_m_s` (m)."""
        return {name: speed_m_s * tau for name, tau in self.response_s.items() if tau > 0}

    def readings_per_bin(self, speed_m_s: float) -> float:
        return self.bin_m / (speed_m_s * self.period_s)

    def record(self) -> dict[str, object]:
        """What a cast's plan keeps of it, for whoever makes its profiles later."""
        slowest = self.slowest
        return {
            "bin_m": self.bin_m,
            "min_count": self.min_count,
            "period_s": self.period_s,
            "resolve": list(self.resolve),
            "slowest": None if slowest is None else slowest[0],
            "descent_limit_m_s": round(self.descent_limit_m_s, 6),
            "dwell_s": self.dwell_s,
        }

    def describe(self, mode: str, winch_m_s: float, floor_m_s: float) -> tuple[str, bool]:
        """One line on what a cast in `mode` on this winch resolves, and whether the
        winch falls short of it (it cannot descend as slowly as the limit asks)."""
        slowest = self.slowest
        why = (
            f"{slowest[0]} {slowest[1]:g} s"
            if slowest is not None and slowest[1] > 0
            else "no response time to honour"
        )
        if mode == "stepped":
            return (
                f"stepped casts dwell >= {self.dwell_s:g} s a level (3 x {why}); "
                f"profiles on {self.bin_m:g} m bins",
                False,
            )
        speed = self.descent_m_s(winch_m_s, floor_m_s)
        lags = ", ".join(f"{name} {lag:.2f} m" for name, lag in self.lags_m(speed).items())
        short = speed > self.descent_limit_m_s * (1 + 1e-9)
        line = (
            f"continuous casts descend at {speed:.3g} m/s (limit {self.descent_limit_m_s:.3g} "
            f"m/s from {self.bin_m:g} m bins, {why}, >= {self.min_count} readings a bin; "
            f"winch {winch_m_s:g} m/s): {self.readings_per_bin(speed):.1f} readings a bin"
            + (f"; lags at that speed: {lags}" if lags else "")
        )
        if short:
            line += f"; the winch cannot descend slower than {floor_m_s:g} m/s"
        return line, short
