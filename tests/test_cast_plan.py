"""The planner: target depth, bottom and line limits, skips, profiles."""

from __future__ import annotations

import pytest

from cc_daemon.core.cast.bottom import AUTOPILOT, ONBOARD, Sounding, distrust, station_for_plan
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


# Issue 19: an untrusted bottom used to plan the full target depth, which on a
# shoal drives the probe into the bed (this replaces the test that pinned that).
@pytest.mark.parametrize(
    ("sonar_mm", "confidence", "why"),
    [
        (2000, 69, "sonar confidence 69 % is under cast.min_sonar_confidence 70 %"),
        (0, 0, "sonar distance 0 mm: no echo"),  # no sonar at all
        (0, 100, "sonar distance 0 mm: no echo"),
        (4294967295, 100, "sonar distance 4294967295 mm cannot be a bottom"),
        (1_000_000, 95, "sonar distance 1000000 mm cannot be a bottom"),
    ],
)
def test_an_untrusted_bottom_casts_blind(sonar_mm: int, confidence: int, why: str) -> None:
    s = settings(target_depth_m=10.0)
    plan = plan_cast(station(sonar_mm=sonar_mm, confidence=confidence), s.cast, 20.0)
    assert isinstance(plan, CastPlan)
    assert (plan.depth_m, plan.limited_by, plan.blind) == (1.0, "blind", why)
    assert plan.water_depth_m is None
    assert plan.legs == (
        Move(1.0, Phase.DESCENDING, slow=True),
        Hold(s.cast.bottom_dwell_s, Phase.DWELLING),
        Move(0.0, Phase.ASCENDING),  # home at the usual speed
    )
    described = plan.describe()
    assert described["blind"] == why and described["limited_by"] == "blind"
    assert described["legs"][0] == {  # type: ignore[index]
        "move_to_m": 1.0,
        "phase": "descending",
        "speed": "approach",
    }


def test_a_blind_cast_is_still_limited_by_the_target_and_slow_on_every_way_down() -> None:
    s = settings(target_depth_m=2.0, blind_max_depth_m=3.0, mode="stepped", step_m=1.0, soak_s=5.0)
    plan = plan_cast(station(sonar_mm=0, confidence=0), s.cast, 20.0)
    assert isinstance(plan, CastPlan)
    assert (plan.depth_m, plan.limited_by) == (2.0, "target")
    assert plan.blind == "sonar distance 0 mm: no echo"  # blind, though not capped
    moves = [leg for leg in plan.legs if isinstance(leg, Move)]
    assert [(m.depth_m, m.slow) for m in moves] == [
        (0.5, True),  # the soak
        (1.0, True),
        (2.0, True),
        (0.0, False),
    ]
    capped = plan_cast(station(sonar_mm=0, confidence=0), s.cast, max_line_m=1.5)
    assert isinstance(capped, CastPlan) and (capped.depth_m, capped.limited_by) == (1.5, "line")


def test_a_trusted_bottom_is_no_blind_cast() -> None:
    s = settings(target_depth_m=10.0)
    plan = plan_cast(station(sonar_mm=30_000, confidence=70), s.cast, 20.0)
    assert isinstance(plan, CastPlan)
    assert (plan.depth_m, plan.blind) == (10.0, None)
    assert not any(isinstance(leg, Move) and leg.slow for leg in plan.legs)
    assert "blind" not in plan.describe()


@pytest.mark.parametrize(
    ("distance_mm", "confidence", "why"),
    [
        (3000, 101, "sonar confidence 101 % is over 100 %: not a reading"),
        (3000, 255, "sonar confidence 255 % is over 100 %: not a reading"),
        (999_999, 100, None),
        (1, 70, None),
        (3000, 0, "sonar confidence 0 % is under cast.min_sonar_confidence 70 %"),
    ],
)
def test_what_a_sonar_reading_must_be_to_be_trusted(
    distance_mm: int, confidence: int, why: str | None
) -> None:
    assert distrust(distance_mm, confidence, min_confidence=70) == why


def test_an_onboard_reading_that_cannot_be_true_is_never_the_bottom() -> None:
    frame = station(sonar_mm=4000, confidence=90)
    for garbage in (Sounding(ONBOARD, 2100, 255, 100.0), Sounding(ONBOARD, 4294967295, 99, 100.0)):
        # Fresher than the frame's reading, and still not chosen.
        assert station_for_plan(frame, 99.5, garbage, min_confidence=70, max_age_s=1.0) == (
            frame,
            AUTOPILOT,
        )
    blank = station(sonar_mm=0, confidence=0)
    chosen, source = station_for_plan(
        blank, 100.0, Sounding(ONBOARD, 2100, 255, 100.0), min_confidence=70, max_age_s=1.0
    )
    assert (chosen, source) == (blank, None)  # no bottom: the planner casts blind


def test_line_length_limits_the_depth() -> None:
    s = settings(target_depth_m=15.0)
    plan = plan_cast(station(sonar_mm=50_000), s.cast, max_line_m=12.0)
    assert isinstance(plan, CastPlan)
    assert (plan.depth_m, plan.limited_by) == (12.0, "line")


# 0 mm is no echo, not a bottom at the surface (issue 19): it casts blind, above.
@pytest.mark.parametrize("sonar_mm", [1, 500, 799])
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
