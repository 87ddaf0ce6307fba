"""A cast that can resolve what it measures: the plan's descent limit and stepped dwells
from `response_s` and `profile.bin_m`, carried to the winches; only ever slower."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cc_daemon.config import Settings
from cc_daemon.config.resolution import cast_resolution
from cc_daemon.core.cast.plan import CastPlan, Hold, Move, Phase, plan_cast
from cc_daemon.core.cast.resolution import Resolution
from cc_daemon.core.winch.physics import LinePhysics
from cc_daemon.core.winch.status import LimitedSpeed
from tests.castkit import drive, station
from tests.gpiokit import enable_history, gpio_rig

TEMPERATURE_ONLY = Resolution(0.25, 2, 1.0, {"temperature": 2.0, "do": 8.0}, ("temperature",))


def sonde_settings(**sections: Any) -> Settings:
    return Settings.model_validate({"sonde": {"backend": "sim"}, **sections})


def planned(s: Settings) -> CastPlan:
    plan = plan_cast(station(sonar_mm=30_000), s.cast, s.winch.max_line_m, cast_resolution(s))
    assert isinstance(plan, CastPlan)
    return plan


def test_the_defaults_descend_one_bin_per_temperature_response_time() -> None:
    plan = planned(sonde_settings())
    assert plan.legs[0] == Move(5.0, Phase.DESCENDING, max_speed_m_s=0.125)
    assert plan.legs[1:] == (Hold(10.0, Phase.DWELLING), Move(0.0, Phase.ASCENDING))
    profile = plan.describe()["profile"]
    assert profile == {
        "bin_m": 0.25, "min_count": 2, "period_s": 1.0, "resolve": ["temperature"],
        "slowest": "temperature", "descent_limit_m_s": 0.125, "dwell_s": 6.0,
    }  # fmt: skip
    assert plan.describe()["legs"][0]["max_speed_m_s"] == 0.125  # type: ignore[index]


def test_readings_per_bin_limit_when_no_sensor_is_slower() -> None:
    # Resolving nothing slow: one bin per min_count readings still holds.
    s = sonde_settings(profile={"resolve": [], "min_count": 4, "bin_m": 0.5})
    assert planned(s).legs[0] == Move(5.0, Phase.DESCENDING, max_speed_m_s=0.125)
    s = sonde_settings(profile={"resolve": ["do_concentration"]})
    assert planned(s).legs[0].max_speed_m_s == pytest.approx(0.25 / 8)  # type: ignore[union-attr]


def test_stepped_dwells_last_three_response_times_of_the_slowest() -> None:
    s = sonde_settings(cast={"mode": "stepped", "step_m": 2.0, "dwell_s": 5.0})
    plan = planned(s)
    assert [leg.seconds for leg in plan.legs if isinstance(leg, Hold)] == [6.0, 6.0, 6.0]
    assert all(leg.max_speed_m_s is None for leg in plan.legs if isinstance(leg, Move))
    s = sonde_settings(
        cast={"mode": "stepped", "step_m": 2.0, "dwell_s": 5.0},
        profile={"resolve": ["do_concentration"]},
    )
    assert {leg.seconds for leg in planned(s).legs if isinstance(leg, Hold)} == {24.0}
    # A dwell already longer is kept.
    s = sonde_settings(cast={"mode": "stepped", "step_m": 2.0, "dwell_s": 30.0})
    assert {leg.seconds for leg in planned(s).legs if isinstance(leg, Hold)} == {30.0}


def test_without_a_sonde_nothing_is_limited() -> None:
    s = Settings()
    assert cast_resolution(s) is None
    plan = planned(s)
    assert plan.legs[0] == Move(5.0, Phase.DESCENDING) and "profile" not in plan.describe()


def test_a_map_without_temperature_resolves_only_what_it_has() -> None:
    parameters = [{"name": "depth", "register": 40001, "unit": "m", "long_name": "d"}]
    s = sonde_settings(sonde={"backend": "sim", "parameters": parameters})
    resolution = cast_resolution(s)
    assert resolution is not None and resolution.resolve == ()
    assert resolution.descent_limit_m_s == 0.125  # one bin per two readings


@given(
    bin_m=st.floats(0.01, 5.0),
    min_count=st.integers(1, 100),
    period_s=st.floats(0.1, 60.0),
    response=st.floats(0.0, 600.0),
    winch=st.floats(0.01, 3.0),
)
def test_the_limit_only_ever_slows_a_cast_down(
    bin_m: float, min_count: int, period_s: float, response: float, winch: float
) -> None:
    resolution = Resolution(bin_m, min_count, period_s, {"t": response}, ("t",))
    floor = winch * 0.5
    speed = resolution.descent_m_s(winch, floor)
    assert floor <= speed <= winch
    assert speed == pytest.approx(max(min(winch, resolution.descent_limit_m_s), floor))
    physics = LinePhysics(speed_m_s=winch, max_line_m=20.0)
    physics.command(0.0, 10.0, max_speed_m_s=resolution.descent_limit_m_s)
    arrival = physics.arrival_time(0.0)
    assert arrival is not None and 10.0 / arrival == pytest.approx(speed)


def test_describe_says_when_the_winch_cannot_go_as_slowly_as_asked() -> None:
    line, short = TEMPERATURE_ONLY.describe("continuous", 0.25, 0.125)
    assert not short and "descend at 0.125 m/s" in line and "2.0 readings a bin" in line
    assert "temperature 0.25 m" in line and "do 1.00 m" in line
    slow = Resolution(0.25, 2, 1.0, {"do": 8.0}, ("do",))
    line, short = slow.describe("continuous", 0.25, 0.125)
    assert short and "cannot descend slower than 0.125 m/s" in line
    assert "limit 0.0312 m/s" in line


def test_a_driven_cast_descends_at_the_limit_and_comes_home_at_full_speed() -> None:
    plan = planned(sonde_settings())
    physics = LinePhysics(speed_m_s=0.25, max_line_m=20.0)
    _, run = drive(plan, physics)
    (down_at, down), (up_at, _) = run.commands
    # 5 m at 0.125 m/s, then the 10 s dwell, then 5 m home at 0.25 m/s.
    assert down == 5.0 and up_at - down_at == pytest.approx(40.0 + 10.0)
    assert run.finished[0][0] - up_at == pytest.approx(20.0)


async def test_the_gpio_winch_scales_its_duty_no_lower_than_the_approach_duty() -> None:
    async with gpio_rig() as rig:
        assert isinstance(rig.winch, LimitedSpeed)
        rig.enable_pin.clear_states()
        rig.winch.move_at_most(1.5, 0.7)  # the kit's line_speed_m_s 1.0: 70 % of the duty
        await rig.settle()
        assert not rig.winch.status().moving and rig.winch.status().fault is None
        assert max(duty for _, duty in enable_history(rig)) == pytest.approx(0.9 * 0.7)
        rig.enable_pin.clear_states()
        rig.winch.move_at_most(2.5, 0.01)  # slower than it runs: its approach duty
        await rig.settle()
        assert max(duty for _, duty in enable_history(rig)) == pytest.approx(0.45)
        rig.enable_pin.clear_states()
        rig.winch.move_at_most(3.0, 5.0)  # faster than it runs: its own duty, no more
        await rig.settle()
        assert max(duty for _, duty in enable_history(rig)) == pytest.approx(0.9)
        assert math.isclose(rig.winch.status().depth_m, 3.0, abs_tol=0.15)
