"""Station memory: one station, one cast, however often `M` is resent.

The deployed firmware resends its selected frame every second, so `M` arrives
many times per station: during the cast (answered with R-O, nothing started)
and after it (answered with R-F again, so the autopilot moves on). A station
counts as done for `rearm_s` seconds within `rearm_distance_m` of where its
cast was asked for. Pure: positions in, decisions out; time is passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cc_daemon.core.protocol import StartMeasuring

EARTH_RADIUS_M = 6_371_008.8  # mean Earth radius (IUGG)


def distance_m(lat1_e7: int, lon1_e7: int, lat2_e7: int, lon2_e7: int) -> float:
    """Great-circle distance (haversine) between two positions in degrees * 1e7."""
    lat1, lat2 = math.radians(lat1_e7 / 1e7), math.radians(lat2_e7 / 1e7)
    dlat = lat2 - lat1
    dlon = math.radians((lon2_e7 - lon1_e7) / 1e7)
    h = math.sin(dlat / 2) ** 2 + math.cos(lat1) * math.cos(lat2) * math.sin(dlon / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(h)))


@dataclass(frozen=True, slots=True)
class DoneStation:
    lat_e7: int
    lon_e7: int
    finished_at: float  # monotonic seconds
    cast_id: int | None


class StationMemory:
    def __init__(self, rearm_s: float, rearm_distance_m: float) -> None:
        self.rearm_s = rearm_s
        self.rearm_distance_m = rearm_distance_m
        self._last: DoneStation | None = None

    def finished(self, station: StartMeasuring, at: float, cast_id: int | None) -> None:
        """A cast asked for at `station` ended (R-F sent) at monotonic time `at`."""
        self._last = DoneStation(station.lat_e7, station.lon_e7, at, cast_id)

    def recently_done(self, station: StartMeasuring, now: float) -> DoneStation | None:
        """The finished station this `M` repeats, if it is one."""
        last = self._last
        if last is None or now - last.finished_at >= self.rearm_s:
            return None
        far = distance_m(last.lat_e7, last.lon_e7, station.lat_e7, station.lon_e7)
        return last if far <= self.rearm_distance_m else None
