"""The simulated mission: reproducible, around the manual's position, one shoal."""

from __future__ import annotations

import itertools
import random

import pytest

from cc_daemon.sim.mission import (
    MIN_CASTABLE_WATER_M,
    ORIGIN_LAT_DEG,
    ORIGIN_LON_DEG,
    SHALLOW_WATER_M,
    SONAR_MAX_NOISE_M,
    Point,
    make_mission,
    to_lat_lon,
)


def test_same_seed_same_mission_and_different_seed_different_mission() -> None:
    assert make_mission(5, seed=7) == make_mission(5, seed=7)
    assert make_mission(5, seed=7) != make_mission(5, seed=8)


@pytest.mark.parametrize("seed", range(20))
@pytest.mark.parametrize("count", [2, 3, 6])
def test_exactly_one_station_is_too_shallow_and_never_the_first(seed: int, count: int) -> None:
    mission = make_mission(count, seed)
    shallow = [s for s in mission.stations if s.too_shallow]
    assert len(shallow) == 1
    assert shallow[0].number != 1
    assert shallow[0].water_depth_m == pytest.approx(SHALLOW_WATER_M, abs=1e-3)
    # With the default plan (0.5 m clearance, 0.3 m minimum) only the shoal is refused.
    for station in mission.stations:
        castable = station.water_depth_m + SONAR_MAX_NOISE_M - 0.5 >= 0.3
        assert castable is not station.too_shallow
        if not station.too_shallow:
            assert station.water_depth_m >= MIN_CASTABLE_WATER_M - 1e-3


def test_one_station_has_no_shoal_and_zero_stations_is_refused() -> None:
    assert not make_mission(1, 3).stations[0].too_shallow
    with pytest.raises(ValueError, match="stations=0"):
        make_mission(0)


@pytest.mark.parametrize("seed", range(10))
def test_stations_are_a_few_hundred_metres_apart_near_the_manuals_position(seed: int) -> None:
    mission = make_mission(4, seed)
    for i in range(4):
        length = mission.leg_length_m(i)
        assert (150 if i == 0 else 200) <= length <= 400
    for a, b in itertools.combinations(mission.stations, 2):
        assert a.point.distance_to(b.point) >= 180
    for station in mission.stations:
        lat, lon = station.point.lat_lon
        assert abs(lat - ORIGIN_LAT_DEG) < 0.02
        assert abs(lon - ORIGIN_LON_DEG) < 0.03


def test_local_metres_convert_to_degrees() -> None:
    assert to_lat_lon(0, 0) == (ORIGIN_LAT_DEG, ORIGIN_LON_DEG)
    lat, _ = to_lat_lon(0, 1000)
    assert lat - ORIGIN_LAT_DEG == pytest.approx(0.008993, abs=1e-6)  # 1 km north
    _, lon = to_lat_lon(1000, 0)
    assert lon - ORIGIN_LON_DEG == pytest.approx(0.011827, abs=1e-5)  # 1 km east at 40.45 N
    assert Point(0, 0).e7 == (-37260579, 404506308)


def test_transit_points_lie_on_the_straight_line() -> None:
    a, b = Point(0, 0), Point(300, 400)
    assert a.towards(b, 250) == Point(150, 200)
    assert a.towards(b, 900) == b
    assert a.towards(a, 5) == a


def test_the_depth_field_is_smooth() -> None:
    field = make_mission(3, 2).field
    for east, north in [(0, 0), (100, -50), (-300, 200)]:
        here = field.depth_at(Point(east, north))
        step = field.depth_at(Point(east + 1, north))
        assert abs(here - step) < 0.1  # a metre over changes the depth by centimetres


def test_sonar_reads_the_field_with_bounded_noise_and_a_confidence() -> None:
    mission = make_mission(3, 4)
    rng = random.Random(0)
    station = mission.stations[0]
    readings = [mission.sonar(station.point, moving=False, rng=rng) for _ in range(500)]
    for r in readings:
        assert abs(r.distance_mm / 1000 - station.water_depth_m) <= SONAR_MAX_NOISE_M + 1e-3
        assert 92 <= r.confidence_pct <= 100
    assert len({r.distance_mm for r in readings}) > 10  # it is noisy
    under_way = mission.sonar(station.point, moving=True, rng=rng)
    assert 75 <= under_way.confidence_pct <= 90
