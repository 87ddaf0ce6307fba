"""Station memory (one station, one cast) and R-frame timestamps."""

from __future__ import annotations

import pytest

from cc_daemon.core.cast.stations import StationMemory, distance_m
from cc_daemon.core.cast.timestamps import AutopilotTime
from tests.castkit import MADRID_LAT_E7, MADRID_LON_E7, station


def test_distance_of_a_known_pair() -> None:
    # 0.0001 degree of latitude is about 11.1 m everywhere.
    assert distance_m(MADRID_LAT_E7, MADRID_LON_E7, MADRID_LAT_E7 + 1000, MADRID_LON_E7) == (
        pytest.approx(11.12, abs=0.01)
    )
    assert distance_m(0, 0, 0, 0) == 0.0


def test_a_repeated_m_at_the_same_station_is_done() -> None:
    memory = StationMemory(rearm_s=120, rearm_distance_m=10)
    here = station()
    assert memory.recently_done(here, 0.0) is None
    memory.finished(here, 100.0, cast_id=7)
    done = memory.recently_done(station(lat_e7=MADRID_LAT_E7 + 500), 150.0)  # 5.6 m away
    assert done is not None and done.cast_id == 7


def test_a_station_rearms_after_time_or_distance() -> None:
    memory = StationMemory(rearm_s=120, rearm_distance_m=10)
    memory.finished(station(), 100.0, cast_id=1)
    assert memory.recently_done(station(), 220.0) is None  # 120 s later
    assert memory.recently_done(station(lat_e7=MADRID_LAT_E7 + 1000), 110.0) is None  # 11 m away


def test_timestamps_follow_the_autopilot_clock() -> None:
    clock = AutopilotTime(started_at=50.0)
    assert clock.at(50.0) == 0
    assert clock.at(52.9) == 2  # whole seconds since start before any frame
    clock.observe(72, now=60.0)
    assert clock.at(60.0) == 72
    assert clock.at(61.99) == 73
    clock.observe(65535, now=70.0)
    assert clock.at(72.0) == 1  # modulo 65536
    clock.observe(0, now=80.0)  # a firmware stuck at 0 is taken as it is
    assert clock.at(80.5) == 0
