"""The cast planner: from a start-measuring frame and the settings, a plan.

Pure. It decides how deep the probe goes and the legs of the profile; it does
not move anything. Depths are metres below the surface, positive down.

A frame whose sonar reading cannot be trusted (`bottom.distrust`: no sonar,
low confidence, a sentinel distance) gives no bottom to stop above, so the
cast goes **blind**: never deeper than `cast.blind_max_depth_m`, every move
down at the winch's approach speed (`Move.slow`), and the sonde's bottom
contact, where a sonde is fitted, still stops the descent. Planning the full
target depth there would drive the probe into the bed of a shoal.

With a sonde, the survey's wanted resolution (`resolution.Resolution`) limits a
continuous descent's speed (`Move.max_speed_m_s`) and lengthens a stepped cast's
dwells to what its slowest sensor needs; it only ever slows a cast down.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Literal, Protocol

from cc_daemon.core.cast.bottom import distrust
from cc_daemon.core.cast.resolution import Resolution
from cc_daemon.core.protocol import StartMeasuring

# A stop a hair shallower than the target is not worth a separate dwell.
_LEVEL_EPSILON_M = 0.01


class CastSettingsLike(Protocol):
    """The `[cast]` settings the planner reads (satisfied by the config model)."""

    @property
    def target_depth_m(self) -> float: ...
    @property
    def min_sonar_confidence(self) -> int: ...
    @property
    def bottom_clearance_m(self) -> float: ...
    @property
    def min_depth_m(self) -> float: ...
    @property
    def mode(self) -> str: ...
    @property
    def bottom_dwell_s(self) -> float: ...
    @property
    def step_m(self) -> float: ...
    @property
    def dwell_s(self) -> float: ...
    @property
    def soak_s(self) -> float: ...
    @property
    def soak_depth_m(self) -> float: ...
    @property
    def blind_max_depth_m(self) -> float: ...


class Phase(StrEnum):
    """The states of a cast; every one but FINISHED is recorded with samples."""

    SOAKING = "soaking"
    DESCENDING = "descending"
    DWELLING = "dwelling"
    ASCENDING = "ascending"
    ABORTING = "aborting"  # bringing the probe home after a fault, a timeout or a shutdown
    STRANDED = "stranded"  # the probe cannot be brought home: operator needed
    FINISHED = "finished"  # the probe is home and R-F has been sent


@dataclass(frozen=True, slots=True)
class Move:
    """Run the winch to `depth_m` (0 means home); `slow`: at its approach speed;
    `max_speed_m_s`: no faster than that (a profile's resolution)."""

    depth_m: float
    phase: Phase
    slow: bool = False
    max_speed_m_s: float | None = None


@dataclass(frozen=True, slots=True)
class Hold:
    """Keep the probe where it is for `seconds`."""

    seconds: float
    phase: Phase


Leg = Move | Hold
LimitedBy = Literal["target", "bottom", "line", "blind"]


@dataclass(frozen=True, slots=True)
class CastPlan:
    depth_m: float
    limited_by: LimitedBy
    water_depth_m: float | None  # from the sonar, when it was confident enough
    mode: str
    legs: tuple[Leg, ...]
    blind: str | None = None  # why no bottom could be trusted: the cast goes blind
    profile: dict[str, object] | None = None  # the resolution it was planned for

    def describe(self) -> dict[str, object]:
        described: dict[str, object] = {
            "depth_m": self.depth_m,
            "limited_by": self.limited_by,
            "water_depth_m": self.water_depth_m,
            "mode": self.mode,
            "legs": [_describe(leg) for leg in self.legs],
        }
        if self.blind is not None:
            described["blind"] = self.blind
        if self.profile is not None:
            described["profile"] = self.profile
        return described


def _describe(leg: Leg) -> dict[str, object]:
    if isinstance(leg, Hold):
        return {"hold_s": leg.seconds, "phase": str(leg.phase)}
    move: dict[str, object] = {"move_to_m": leg.depth_m, "phase": str(leg.phase)}
    if leg.slow:
        move["speed"] = "approach"
    if leg.max_speed_m_s is not None:
        move["max_speed_m_s"] = round(leg.max_speed_m_s, 6)
    return move


@dataclass(frozen=True, slots=True)
class SkipCast:
    """The station is too shallow to cast at."""

    planned_depth_m: float
    water_depth_m: float | None
    reason: str


def plan_cast(
    station: StartMeasuring,
    settings: CastSettingsLike,
    max_line_m: float,
    resolution: Resolution | None = None,
) -> CastPlan | SkipCast:
    depth = settings.target_depth_m
    limited_by: LimitedBy = "target"
    water_depth: float | None = None
    blind = distrust(
        station.sonar_distance_mm,
        station.sonar_confidence_pct,
        min_confidence=settings.min_sonar_confidence,
    )
    if blind is None:
        water_depth = station.sonar_distance_mm / 1000.0
        above_bottom = water_depth - settings.bottom_clearance_m
        if above_bottom < depth:
            depth, limited_by = above_bottom, "bottom"
    elif settings.blind_max_depth_m < depth:
        depth, limited_by = settings.blind_max_depth_m, "blind"
    if max_line_m < depth:
        depth, limited_by = max_line_m, "line"
    if depth < settings.min_depth_m:
        # One value for the record and the reason: a bottom inside the clearance
        # plans no descent at all (0 m), never a negative depth.
        planned = max(depth, 0.0)
        return SkipCast(
            planned_depth_m=planned,
            water_depth_m=water_depth,
            reason=(
                f"planned depth {planned:.2f} m ({limited_by}-limited: sonar {water_depth} m, "
                f"clearance {settings.bottom_clearance_m} m) is under min_depth_m "
                f"{settings.min_depth_m} m"
            ),
        )
    slow = blind is not None  # down at the approach speed: the bed may be anywhere below
    legs: list[Leg] = []
    if settings.soak_s > 0 and settings.soak_depth_m < depth:
        legs += [
            Move(settings.soak_depth_m, Phase.SOAKING, slow),
            Hold(settings.soak_s, Phase.SOAKING),
        ]
    if settings.mode == "stepped":
        dwell = max(settings.dwell_s, resolution.dwell_s if resolution else 0.0)
        level = settings.step_m
        while level < depth - _LEVEL_EPSILON_M:
            legs += [Move(level, Phase.DESCENDING, slow), Hold(dwell, Phase.DWELLING)]
            level += settings.step_m
        legs += [Move(depth, Phase.DESCENDING, slow), Hold(dwell, Phase.DWELLING)]
    else:
        limit = resolution.descent_limit_m_s if resolution else None
        legs += [
            Move(depth, Phase.DESCENDING, slow, limit),
            Hold(settings.bottom_dwell_s, Phase.DWELLING),
        ]
    legs.append(Move(0.0, Phase.ASCENDING))
    return CastPlan(
        depth_m=depth,
        limited_by=limited_by,
        water_depth_m=water_depth,
        mode=settings.mode,
        legs=tuple(legs),
        blind=blind,
        profile=resolution.record() if resolution else None,
    )
