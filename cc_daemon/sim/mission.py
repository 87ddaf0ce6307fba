"""A reproducible survey mission: stations, transits and the water under the boat.

This module owns the simulated world the autopilot moves through: a handful
of stations a few hundred metres apart around the manual's position (40.4506308
N, 3.7260579 W, 702.385 m), straight-line transits between them, a smooth
water-depth field with a shoal (one station is too shallow to cast at), and an
echosounder that reads that field with noise and a confidence.

Everything here is a pure function of the seed and the arguments: the same
`make_mission(stations, seed)` gives the same mission, and the sonar's noise
comes from a `random.Random` the caller owns. No I/O, no clock.
"""

from __future__ import annotations

import itertools
import math
import random
from dataclasses import dataclass, replace
from types import SimpleNamespace
from typing import Any

ORIGIN_LAT_DEG = 40.4506308
ORIGIN_LON_DEG = -3.7260579
ORIGIN_ALT_M = 702.385  # the manual's altitude: a reservoir north-west of Madrid
EARTH_RADIUS_M = 6_371_000.0

SHALLOW_WATER_M = 0.6  # the shoal station: 0.6 - 0.5 m clearance < 0.3 m minimum
MIN_CASTABLE_WATER_M = 2.5  # every other station has at least this much water
SONAR_NOISE_M = 0.02  # one standard deviation, clipped at three
SONAR_MAX_NOISE_M = 0.05
_SHOAL_RADIUS_M = 40.0
_MIN_SPACING_M = 180.0  # 4.5 shoal radii: the shoal's effect there is under 0.1 mm
_PLACEMENT_ATTEMPTS = 100  # per station, before the mission is refused
# The functions `DepthField.depth_xy` needs, for one position (numpy gives them for arrays).
SCALAR = SimpleNamespace(
    sin=math.sin, cos=math.cos, exp=math.exp, fmax=max, fabs=math.fabs, log1p=math.log1p
)


def to_lat_lon(east_m: float, north_m: float) -> tuple[float, float]:
    """Local east/north metres from the origin to (lat, lon) degrees."""
    lat = ORIGIN_LAT_DEG + math.degrees(north_m / EARTH_RADIUS_M)
    lon = ORIGIN_LON_DEG + math.degrees(
        east_m / (EARTH_RADIUS_M * math.cos(math.radians(ORIGIN_LAT_DEG)))
    )
    return lat, lon


def from_lat_lon(lat: Any, lon: Any) -> tuple[Any, Any]:
    """`to_lat_lon` undone: (east, north) metres from the origin, for numbers or arrays."""
    north = (lat - ORIGIN_LAT_DEG) * (math.pi / 180.0) * EARTH_RADIUS_M
    east = (lon - ORIGIN_LON_DEG) * (math.pi / 180.0) * EARTH_RADIUS_M
    return east * math.cos(math.radians(ORIGIN_LAT_DEG)), north


@dataclass(frozen=True, slots=True)
class Point:
    """A position in local metres east and north of the origin."""

    east_m: float
    north_m: float

    def distance_to(self, other: Point) -> float:
        return math.hypot(other.east_m - self.east_m, other.north_m - self.north_m)

    def towards(self, other: Point, metres: float) -> Point:
        """The point `metres` along the straight line to `other` (clamped at `other`)."""
        total = self.distance_to(other)
        if total == 0 or metres >= total:
            return other
        f = max(metres, 0.0) / total
        return Point(
            self.east_m + (other.east_m - self.east_m) * f,
            self.north_m + (other.north_m - self.north_m) * f,
        )

    @property
    def lat_lon(self) -> tuple[float, float]:
        return to_lat_lon(self.east_m, self.north_m)

    @property
    def e7(self) -> tuple[int, int]:
        """(lon, lat) in the wire's units: degrees times 1e7."""
        lat, lon = self.lat_lon
        return round(lon * 1e7), round(lat * 1e7)


@dataclass(frozen=True, slots=True)
class DepthField:
    """Water depth (metres) as a smooth function of position, with one shoal."""

    base_m: float
    swell_m: float
    ripple_m: float
    wavelength_e_m: float
    wavelength_n_m: float
    phase_e: float
    phase_n: float
    shoal: Point | None
    shoal_relief_m: float  # how much the shoal rises above the smooth bed at its centre
    # 0: the bed is cut flat at MIN_CASTABLE_WATER_M where it would be shallower; more: it
    # levels off smoothly over about this many metres (a lake has no plateau cut level at
    # one depth, which would make a hypsography's area at that depth a coin toss)
    floor_softness_m: float = 0.0

    def smooth_at(self, p: Point) -> float:
        """The bed without the shoal, never shallower than MIN_CASTABLE_WATER_M."""
        return float(self.smooth_xy(p.east_m, p.north_m, SCALAR))

    def depth_at(self, p: Point) -> float:
        return float(self.depth_xy(p.east_m, p.north_m, SCALAR))

    def smooth_xy(self, east: Any, north: Any, xp: Any) -> Any:
        """`smooth_at` of one position (`xp` = SCALAR) or of arrays (`xp` = numpy): the
        same formula either way, so tests and benchmarks can read the true bed of a
        whole grid at once without the simulator importing numpy."""
        d = (
            self.base_m
            + self.swell_m
            * xp.sin(east / self.wavelength_e_m + self.phase_e)
            * xp.cos(north / self.wavelength_n_m + self.phase_n)
            + self.ripple_m * xp.sin((east + north) / 90.0 + self.phase_n)
        )
        soft = self.floor_softness_m
        if soft > 0:
            excess = (d - MIN_CASTABLE_WATER_M) / soft
            return MIN_CASTABLE_WATER_M + soft * (
                xp.fmax(excess, 0.0) + xp.log1p(xp.exp(-xp.fabs(excess)))
            )
        return xp.fmax(d, MIN_CASTABLE_WATER_M)

    def depth_xy(self, east: Any, north: Any, xp: Any) -> Any:
        """The true bed (metres below the surface) at `east`, `north`: see `smooth_xy`."""
        d = self.smooth_xy(east, north, xp)
        if self.shoal is not None:
            r2 = (east - self.shoal.east_m) ** 2 + (north - self.shoal.north_m) ** 2
            d = d - self.shoal_relief_m * xp.exp(-r2 / (2 * _SHOAL_RADIUS_M**2))
        return xp.fmax(d, 0.1)


@dataclass(frozen=True, slots=True)
class Station:
    number: int  # 1-based, as a person counts them
    point: Point
    water_depth_m: float
    too_shallow: bool  # built to be too shallow to cast at (with default cast settings)

    @property
    def name(self) -> str:
        return f"S{self.number}"


@dataclass(frozen=True, slots=True)
class SonarReading:
    distance_mm: int
    confidence_pct: int


@dataclass(frozen=True, slots=True)
class Mission:
    seed: int
    start: Point
    stations: tuple[Station, ...]
    field: DepthField

    # The points each transit passes on its way (the lines of a bathymetric survey,
    # `sim.lines`): transit i goes through waypoints[i] in order; none: straight.
    waypoints: tuple[tuple[Point, ...], ...] = ()

    def leg(self, index: int) -> tuple[Point, Point]:
        """Transit `index`: from the start (index 0) or the previous station to station `index`."""
        begin = self.start if index == 0 else self.stations[index - 1].point
        return begin, self.stations[index].point

    def path(self, index: int) -> tuple[Point, ...]:
        """Transit `index` as the points it is sailed through, its ends included."""
        begin, end = self.leg(index)
        through = self.waypoints[index] if index < len(self.waypoints) else ()
        return (begin, *through, end)

    def leg_length_m(self, index: int) -> float:
        points = self.path(index)
        return sum(a.distance_to(b) for a, b in itertools.pairwise(points))

    def along_leg(self, index: int, metres: float) -> Point:
        """The point `metres` along transit `index` (clamped at its end)."""
        points = self.path(index)
        for a, b in itertools.pairwise(points):
            step = a.distance_to(b)
            if metres < step:
                return a.towards(b, metres)
            metres -= step
        return points[-1]

    @property
    def total_distance_m(self) -> float:
        return sum(self.leg_length_m(i) for i in range(len(self.stations)))

    def sonar(self, p: Point, *, moving: bool, rng: random.Random) -> SonarReading:
        """What the echosounder says at `p`: the true depth plus noise, with a confidence.

        Under way the returns are noisier (confidence 75-90 %); holding
        station they are clean (92-100 %), so a station's plan can trust them.
        """
        noise = max(-SONAR_MAX_NOISE_M, min(SONAR_MAX_NOISE_M, rng.gauss(0.0, SONAR_NOISE_M)))
        distance = max(self.field.depth_at(p) + noise, 0.0)
        confidence = rng.randint(75, 90) if moving else rng.randint(92, 100)
        return SonarReading(round(distance * 1000), confidence)


def random_field(
    rng: random.Random, shoal: Point | None, *, floor_softness_m: float = 0.0
) -> DepthField:
    """A smooth bed drawn from `rng`, with a shoal rising to SHALLOW_WATER_M at `shoal`."""
    smooth = DepthField(
        base_m=rng.uniform(4.5, 6.0),
        swell_m=rng.uniform(1.0, 2.0),
        ripple_m=rng.uniform(0.3, 0.8),
        wavelength_e_m=rng.uniform(120.0, 220.0),
        wavelength_n_m=rng.uniform(150.0, 260.0),
        phase_e=rng.uniform(0.0, 2 * math.pi),
        phase_n=rng.uniform(0.0, 2 * math.pi),
        shoal=None,
        shoal_relief_m=0.0,
        floor_softness_m=floor_softness_m,
    )
    if shoal is None:
        return smooth
    return replace(smooth, shoal=shoal, shoal_relief_m=smooth.smooth_at(shoal) - SHALLOW_WATER_M)


def make_mission(stations: int = 3, seed: int = 1) -> Mission:
    """A mission of `stations` stations; the same arguments always give the same mission.

    With two or more stations, one of them (never the first, so the demo
    shows a cast before a refusal) sits on a shoal in SHALLOW_WATER_M of water.
    Raises ValueError if a station cannot be placed far enough from the others
    (the meandering line boxed itself in).
    """
    if stations < 1:
        raise ValueError(f"stations={stations} is invalid: allowed >= 1")
    rng = random.Random(seed)
    start = Point(0.0, 0.0)
    heading = rng.uniform(0.0, 2 * math.pi)
    points: list[Point] = []
    here = start
    for i in range(stations):
        # A meandering line; a station never lands within _MIN_SPACING_M of
        # an earlier one, so the shoal cannot shade a second station.
        for _attempt in range(_PLACEMENT_ATTEMPTS):
            turn = heading + rng.uniform(-0.9, 0.9)
            step = rng.uniform(150.0, 250.0) if i == 0 else rng.uniform(200.0, 400.0)
            candidate = Point(
                here.east_m + step * math.sin(turn), here.north_m + step * math.cos(turn)
            )
            if all(candidate.distance_to(p) >= _MIN_SPACING_M for p in points):
                break
            heading += rng.uniform(-math.pi, math.pi)  # boxed in: try another direction
        else:
            raise ValueError(
                f"stations={stations}, seed={seed}: station {i + 1} cannot be placed "
                f"{_MIN_SPACING_M:g} m from the others in {_PLACEMENT_ATTEMPTS} tries; "
                "try another seed or fewer stations"
            )
        heading, here = turn, candidate
        points.append(here)
    shallow_index = rng.randrange(1, stations) if stations >= 2 else None
    field = random_field(rng, points[shallow_index] if shallow_index is not None else None)
    built = tuple(
        Station(i + 1, p, round(field.depth_at(p), 3), i == shallow_index)
        for i, p in enumerate(points)
    )
    return Mission(seed=seed, start=start, stations=built, field=field)
