"""Which of a cast's depths are estimates, and within what range: what the journal's
events say about the depth samples, so no plot or file shows a guess as a measure.

The winch journals its depth once a second as a number (`samples`). When its
count stops being trusted (a dead or babbling encoder: docs/gpio-winch.md), the
number it gives is its best estimate, and the `winch_fault` event it journals
then says where the probe may be: `depth_low_m` to `depth_high_m`. From that
event to the end of the cast every sample is such an estimate: the count is
trusted again only from home, where the cast ends. (The range widens as an
operator hauls blind; the journal keeps the first, so each sample's range is
widened to hold its own best estimate.)

Between two samples the winch may go deeper than either shows (a stall 0.2 s
after a sample, the probe hauled up before the next): the depth a cast's
`cast_aborted` or `cast_stranded` event gives is the winch's own at that
instant, and belongs in the trace beside the samples (`event_points`).

Pure: records in, ranges out; it never reads the journal.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import NamedTuple

from cc_daemon.store.records import CastRecord, EventRecord, SampleRecord

# The events whose `depth_m` is the winch's depth at that instant, in a cast.
DEPTH_EVENTS = ("cast_aborted", "cast_stranded")


class Estimate(NamedTuple):
    """From `since_mono_s` on, the cast's depths are estimates within [low_m, high_m]."""

    since_mono_s: float
    low_m: float
    high_m: float
    by: str  # how the best estimate was made: "dead reckoning", "the count"


class Point(NamedTuple):
    """A depth in a cast's trace: a sample, or the winch's depth at an event."""

    mono_s: float
    depth_m: float
    phase: str
    low_m: float | None  # None: measured; else the range an estimate lies in
    high_m: float | None
    sampled: bool  # False: the depth an event recorded (between two samples)


def _within(cast: CastRecord, event: EventRecord) -> bool:
    if event.session_id != cast.session_id:
        return False
    end = cast.end_mono_s if cast.end_mono_s is not None else math.inf
    return cast.start_mono_s <= event.mono_s <= end


def _number(value: object) -> float | None:
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return None


def of_casts(casts: Iterable[CastRecord], events: Sequence[EventRecord]) -> dict[int, Estimate]:
    """Each cast's estimate, by cast id: those with none are measured throughout."""
    found: dict[int, Estimate] = {}
    ranged = [e for e in events if e.kind == "winch_fault" and "depth_low_m" in e.detail]
    for cast in casts:
        for event in ranged:
            low, high = (
                _number(event.detail["depth_low_m"]),
                _number(event.detail.get("depth_high_m")),
            )
            if low is None or high is None or not _within(cast, event):
                continue
            by = event.detail.get("depth_by")
            found[cast.id] = Estimate(event.mono_s, low, high, by if isinstance(by, str) else "")
            break
    return found


def band(estimate: Estimate | None, mono_s: float, depth_m: float) -> tuple[float, float] | None:
    """The range a depth recorded at `mono_s` lies in; None if it was measured."""
    if estimate is None or mono_s < estimate.since_mono_s:
        return None
    return min(estimate.low_m, depth_m), max(estimate.high_m, depth_m)


def trace(
    cast: CastRecord,
    samples: Sequence[SampleRecord],
    events: Sequence[EventRecord],
    estimate: Estimate | None,
) -> list[Point]:
    """The cast's depths in time order: its samples and the depths its events give,
    each with its range when it is an estimate."""
    points = [
        _point(s.mono_s, s.depth_m, s.phase, estimate, sampled=True)
        for s in samples
        if s.cast_id == cast.id
    ]
    for event in events:
        depth = _number(event.detail.get("depth_m"))
        if (
            event.kind in DEPTH_EVENTS
            and event.detail.get("cast_id") == cast.id
            and depth is not None
            and _within(cast, event)
        ):
            phase = "aborting" if event.kind == "cast_aborted" else "stranded"
            points.append(_point(event.mono_s, depth, phase, estimate, sampled=False))
    return sorted(points, key=lambda p: p.mono_s)


def _point(
    mono_s: float, depth_m: float, phase: str, estimate: Estimate | None, *, sampled: bool
) -> Point:
    found = band(estimate, mono_s, depth_m)
    low, high = found if found is not None else (None, None)
    return Point(mono_s, depth_m, phase, low, high, sampled)


def for_samples(
    samples: Iterable[SampleRecord], estimates: Mapping[int, Estimate]
) -> Iterable[tuple[SampleRecord, tuple[float, float] | None]]:
    """Each sample with its range (None: measured), for a file written sample by sample."""
    for s in samples:
        yield s, band(estimates.get(s.cast_id), s.mono_s, s.depth_m)
