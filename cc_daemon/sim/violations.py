"""What the simulated autopilot finds: protocol violations, and each station's log.

This module owns the records the checker in `sim.autopilot` keeps and the
summary reads: the kinds of violation, one violation with its excuse, and
what happened at one station (with its verdict). Plain values: no I/O, no
clock, no decisions beyond a station's verdict.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from cc_daemon.sim.mission import Station


class ViolationKind(StrEnum):
    CORRUPT_FRAME = "corrupt frame"
    NO_ACK = "M not answered"
    NO_PROBE_ANSWER = "S not answered"
    REPORT_GAP = "depth reports stopped"
    FINISHED_NOT_HOME = "R-F with the probe down"
    DEPTH_OUT_OF_RANGE = "depth out of range"
    NO_FINISH = "no R-F"
    UNEXPECTED_FRAME = "unexpected frame"
    UNEXPECTED_SKIP = "deep station not cast"
    UNEXPECTED_CAST = "cast at a too-shallow station"
    DUPLICATE_CAST = "more than one cast at a station"  # found in the daemon's journal


@dataclass(frozen=True, slots=True)
class Violation:
    time: float
    kind: ViolationKind
    detail: str
    station: int | None  # 1-based station number, None between stations
    excused_by: str | None = None  # injected noise or an unplugged cable explains it

    @property
    def excused(self) -> bool:
        return self.excused_by is not None

    def describe(self) -> str:
        where = f"S{self.station} " if self.station is not None else ""
        note = f" (excused: {self.excused_by})" if self.excused_by else ""
        return f"{self.time:7.1f} s  {where}{self.kind}: {self.detail}{note}"


@dataclass(slots=True)
class StationLog:
    """What happened at one station, as the autopilot saw it."""

    station: Station
    arrived_at: float | None = None
    acked_at: float | None = None
    finished_at: float | None = None
    finish_depth_mm: int | None = None
    reports: int = 0
    max_depth_m: float = 0.0
    m_sent: int = 0
    s_sent: int = 0
    stick_down: int = 0  # P-D frames sent (the scripted jog)
    stick_up: int = 0
    fault_reports: int = 0  # R-L frames: the daemon says the probe may be down
    fault_depth_m: float | None = None  # the depth the last R-L carried
    violations: list[Violation] = field(default_factory=list)

    @property
    def cast_duration_s(self) -> float | None:
        """From R-O to R-F."""
        if self.acked_at is None or self.finished_at is None:
            return None
        return self.finished_at - self.acked_at

    @property
    def problems(self) -> list[Violation]:
        return [v for v in self.violations if not v.excused]

    @property
    def verdict(self) -> str:
        if self.arrived_at is None:
            return "not reached"
        if self.finished_at is None:
            if self.fault_reports:
                return f"stranded: R-L x{self.fault_reports}, no R-F"
            return "no R-F"
        if self.problems:
            return "FAILED: " + ", ".join(sorted({str(v.kind) for v in self.problems}))
        if self.reports == 0:
            return "skipped: too shallow" if self.station.too_shallow else "skipped"
        return "measured"


# One wording whichever way the mangled frame went: the run injected the noise both ways.
BITS_FLIPPED = "bits flipped by --corrupt"

# What a lost or mangled frame can explain, by where the noise was.
EXPLAINED_BY_INBOUND_LOSS = frozenset(
    {
        ViolationKind.CORRUPT_FRAME,
        ViolationKind.NO_ACK,
        ViolationKind.NO_PROBE_ANSWER,
        ViolationKind.REPORT_GAP,
    }
)
EXPLAINED_BY_OUTBOUND_LOSS = frozenset({ViolationKind.NO_ACK, ViolationKind.NO_PROBE_ANSWER})
