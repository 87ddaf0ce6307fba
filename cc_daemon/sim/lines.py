"""The pattern an autopilot flies for bathymetry: parallel lines at a set spacing.

This module owns the lines mission (`--pattern lines --spacing 20`): a boat
sailing back and forth along `lines` parallel lines `line_length_m` long and
`spacing_m` apart (east and west, stepping north), at survey speed, with its
stations spread along the way (the last at the pattern's end) and the lake's bed
under it (`mission.random_field`: the same kind of bed as the stations' mission,
its shoal in the middle of the area, as far from every station as it can be, so that every
station can be cast and the map has a hill to show).

Survey speed is a property of the echosounder, not of the demo: soundings one
to two fixes a second at about 1.5 m/s are a metre or so apart along a line, as
a real survey's are, so the lines are sailed at `SURVEY_SPEED_M_S` whatever the
pace. Pure: the same arguments always give the same mission. No I/O, no clock.
"""

from __future__ import annotations

import itertools
import random

from cc_daemon.sim.mission import Mission, Point, Station, random_field

SURVEY_SPEED_M_S = 1.5  # about 3 knots: what single-beam surveys from small boats sail
DEFAULT_SPACING_M = 20.0
DEFAULT_LINES = 4
DEFAULT_LINE_LENGTH_M = 100.0
FLOOR_SOFTNESS_M = 0.5  # the bed levels off smoothly where it would be cut flat


def lines_route(spacing_m: float, lines: int, line_length_m: float) -> tuple[Point, ...]:
    """The turning points of the pattern from its start (0, 0): line i runs along north =
    i x spacing, eastwards on even lines and westwards on odd ones."""
    if spacing_m <= 0 or line_length_m <= 0 or lines < 1:
        raise ValueError(
            f"spacing {spacing_m:g} m, {lines} lines of {line_length_m:g} m: "
            "allowed spacing > 0, lines >= 1, length > 0"
        )
    points: list[Point] = []
    for i in range(lines):
        west, east = Point(0.0, i * spacing_m), Point(line_length_m, i * spacing_m)
        points += [west, east] if i % 2 == 0 else [east, west]
    return tuple(points)


def _length(points: tuple[Point, ...]) -> float:
    return sum(a.distance_to(b) for a, b in itertools.pairwise(points))


def _along(points: tuple[Point, ...], metres: float) -> tuple[Point, int]:
    """The point `metres` along `points`, and how many of them lie before it."""
    for i, (a, b) in enumerate(itertools.pairwise(points)):
        step = a.distance_to(b)
        if metres < step:
            return a.towards(b, metres), i + 1
        metres -= step
    return points[-1], len(points) - 1


def make_lines_mission(
    stations: int = 3,
    seed: int = 1,
    *,
    spacing_m: float = DEFAULT_SPACING_M,
    lines: int = DEFAULT_LINES,
    line_length_m: float = DEFAULT_LINE_LENGTH_M,
) -> Mission:
    """Lines over the bed with `stations` stations evenly along them, the last at the end,
    and a shoal rising to `mission.SHALLOW_WATER_M` in the area's middle, far from them."""
    if stations < 1:
        raise ValueError(f"stations={stations} is invalid: allowed >= 1")
    route = lines_route(spacing_m, lines, line_length_m)
    total = _length(route)
    rng = random.Random(seed)
    placed = [_along(route, total * (k + 1) / stations) for k in range(stations)]
    # In the middle half of the area, where the map can show all of it.
    north = (lines - 1) * spacing_m
    candidates = [
        Point(line_length_m * (0.25 + 0.05 * i), north * (0.25 + 0.05 * j))
        for i in range(11)
        for j in range(11)
    ]
    shoal = max(candidates, key=lambda c: min(c.distance_to(p) for p, _ in placed))
    field = random_field(rng, shoal, floor_softness_m=FLOOR_SOFTNESS_M)
    waypoints: list[tuple[Point, ...]] = []
    before = 1  # the route's first point is the start
    for point, passed in placed:
        waypoints.append(tuple(p for p in route[before:passed] if p != point))
        before = max(before, passed)
    built = tuple(
        Station(i + 1, p, round(field.depth_at(p), 3), too_shallow=False)
        for i, (p, _) in enumerate(placed)
    )
    return Mission(
        seed=seed, start=route[0], stations=built, field=field, waypoints=tuple(waypoints)
    )
