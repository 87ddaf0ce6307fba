"""The planner: target depth, bottom and line limits, skips, profiles."""

from __future__ import annotations

import pytest

from cc_daemon.core.cast.plan import CastPlan, Hold, Move, Phase, SkipCast, plan_cast
from tests.castkit import settings, station


def test_default_plan_goes_to_target_depth_then_dwells_then_home() -> None:
    s = settings()
    plan = plan_cast(station(sonar_mm=30_000), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    assert plan.depth_m == 5.0
    assert plan.limited_by == "target"
    assert plan.legs == (
        Move(5.0, Phase.DESCENDING),
        Hold(s.cast.bottom_dwell_s, Phase.DWELLING),
        Move(0.0, Phase.ASCENDING),
    )


def test_confident_sonar_stops_the_probe_above_the_bottom() -> None:
    s = settings(target_depth_m=10.0)
    plan = plan_cast(station(sonar_mm=8219, confidence=70), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    assert plan.depth_m == pytest.approx(8.219 - 0.5)
    assert plan.limited_by == "bottom"
    assert plan.water_depth_m == pytest.approx(8.219)


def test_unconfident_sonar_is_ignored() -> None:
    s = settings(target_depth_m=10.0)
    plan = plan_cast(station(sonar_mm=2000, confidence=69), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    assert plan.depth_m == 10.0
    assert plan.water_depth_m is None


def test_line_length_limits_the_depth() -> None:
    s = settings(target_depth_m=15.0)
    plan = plan_cast(station(sonar_mm=50_000), s.cast, max_line_m=12.0)
    assert isinstance(plan, CastPlan)
    assert (plan.depth_m, plan.limited_by) == (12.0, "line")


@pytest.mark.parametrize("sonar_mm", [0, 500, 799])
def test_too_shallow_station_is_skipped_with_a_reason(sonar_mm: int) -> None:
    s = settings()
    plan = plan_cast(station(sonar_mm=sonar_mm), s.cast, s.winch.max_line_m)
    assert isinstance(plan, SkipCast)
    assert "min_depth_m" in plan.reason
    assert 0.0 <= plan.planned_depth_m < 0.3
    # The reason and the stored planned depth say the same thing.
    assert f"planned depth {plan.planned_depth_m:.2f} m " in plan.reason
    assert "-0." not in plan.reason


def test_just_deep_enough_is_cast() -> None:
    s = settings()
    plan = plan_cast(station(sonar_mm=800), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    assert plan.depth_m == pytest.approx(0.3)


def test_stepped_profile_stops_at_every_step_and_at_the_target() -> None:
    s = settings(mode="stepped", step_m=1.5, dwell_s=4.0, target_depth_m=5.0)
    plan = plan_cast(station(sonar_mm=30_000), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    moves = [leg.depth_m for leg in plan.legs if isinstance(leg, Move)]
    assert moves == [1.5, 3.0, 4.5, 5.0, 0.0]
    holds = [leg for leg in plan.legs if isinstance(leg, Hold)]
    assert [h.seconds for h in holds] == [4.0] * 4
    assert all(h.phase is Phase.DWELLING for h in holds)


def test_soak_comes_first() -> None:
    s = settings(soak_s=30.0, soak_depth_m=0.5)
    plan = plan_cast(station(sonar_mm=30_000), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    assert plan.legs[:2] == (Move(0.5, Phase.SOAKING), Hold(30.0, Phase.SOAKING))


def test_soak_deeper_than_a_bottom_limited_cast_is_left_out() -> None:
    s = settings(soak_s=30.0, soak_depth_m=1.0)
    plan = plan_cast(station(sonar_mm=1200), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    assert plan.depth_m == pytest.approx(0.7)
    assert all(leg.phase is not Phase.SOAKING for leg in plan.legs)


def test_describe_is_json_ready() -> None:
    s = settings(mode="stepped")
    plan = plan_cast(station(sonar_mm=30_000), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan)
    described = plan.describe()
    assert described["mode"] == "stepped"
    assert described["legs"][-1] == {"move_to_m": 0.0, "phase": "ascending"}  # type: ignore[index]
