"""The cast planner: from a start-measuring frame and the settings, a plan.

Pure. It decides how deep the probe goes and the legs of the profile; it does
not move anything. Depths are metres below the surface, positive down.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Literal, Protocol

from cc_daemon.core.cast.bottom import sounding_valid
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
    """Run the winch to `depth_m` (0 means home)."""

    depth_m: float
    phase: Phase


@dataclass(frozen=True, slots=True)
class Hold:
    """Keep the probe where it is for `seconds`."""

    seconds: float
    phase: Phase


Leg = Move | Hold
LimitedBy = Literal["target", "bottom", "line"]


@dataclass(frozen=True, slots=True)
class CastPlan:
    depth_m: float
    limited_by: LimitedBy
    water_depth_m: float | None  # from the sonar, when it was confident enough
    mode: str
    legs: tuple[Leg, ...]

    def describe(self) -> dict[str, object]:
        return {
            "depth_m": self.depth_m,
            "limited_by": self.limited_by,
            "water_depth_m": self.water_depth_m,
            "mode": self.mode,
            "legs": [
                {"move_to_m": leg.depth_m, "phase": str(leg.phase)}
                if isinstance(leg, Move)
                else {"hold_s": leg.seconds, "phase": str(leg.phase)}
                for leg in self.legs
            ],
        }


@dataclass(frozen=True, slots=True)
class SkipCast:
    """The station is too shallow to cast at."""

    planned_depth_m: float
    water_depth_m: float | None
    reason: str


def plan_cast(
    station: StartMeasuring, settings: CastSettingsLike, max_line_m: float
) -> CastPlan | SkipCast:
    depth = settings.target_depth_m
    limited_by: LimitedBy = "target"
    water_depth: float | None = None
    trusted = sounding_valid(station.sonar_distance_mm, station.sonar_confidence_pct)
    if trusted and station.sonar_confidence_pct >= settings.min_sonar_confidence:
        water_depth = station.sonar_distance_mm / 1000.0
        above_bottom = water_depth - settings.bottom_clearance_m
        if above_bottom < depth:
            depth, limited_by = above_bottom, "bottom"
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
    legs: list[Leg] = []
    if settings.soak_s > 0 and settings.soak_depth_m < depth:
        legs += [Move(settings.soak_depth_m, Phase.SOAKING), Hold(settings.soak_s, Phase.SOAKING)]
    if settings.mode == "stepped":
        level = settings.step_m
        while level < depth - _LEVEL_EPSILON_M:
            legs += [Move(level, Phase.DESCENDING), Hold(settings.dwell_s, Phase.DWELLING)]
            level += settings.step_m
        legs += [Move(depth, Phase.DESCENDING), Hold(settings.dwell_s, Phase.DWELLING)]
    else:
        legs += [Move(depth, Phase.DESCENDING), Hold(settings.bottom_dwell_s, Phase.DWELLING)]
    legs.append(Move(0.0, Phase.ASCENDING))
    return CastPlan(
        depth_m=depth,
        limited_by=limited_by,
        water_depth_m=water_depth,
        mode=settings.mode,
        legs=tuple(legs),
    )
