"""A survey's soundings from the journal: positioned, corrected and judged, as arrays.

This module owns turning the journal's records into soundings the science floor
can map (`science.bathymetry`):
- every fix's own sonar reading, at the fix's position;
- every reading of the companion computer's Ping1D (`sonar_readings`), placed on
  the track by interpolating the two fixes around it in time, within the same
  session (monotonic time, exact within a boot), never across a gap longer than
  `max_gap_s`;
- the depth below the water surface: the distance plus that source's transducer
  draft;
- the quality control (`science.bathymetry.qc`), each rejection with its reason.

Positions are projected to the UTM zone of the survey (pyproj, WGS 84), the
frame every product is gridded in. It never writes, and reads the journal only
through the `JournalReader` it is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cc_daemon.config.survey import SurveySettings
from cc_daemon.science.bathymetry import qc
from cc_daemon.store.sonar import SonarReadingRecord

if TYPE_CHECKING:
    from pyproj import CRS

    from cc_daemon.store.records import FixRecord

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

AUTOPILOT, ONBOARD = 0, 1
SOURCES = ("autopilot", "onboard")
_SEGMENT_STRIDE = 1 << 20  # segment numbers of the two sources never meet


@dataclass(frozen=True, slots=True)
class Soundings:
    """One entry per sounding: the fixes' first, then the Ping1D's, each in time order."""

    source: npt.NDArray[np.int8]
    session: IntArray
    mono_s: FloatArray
    wall_s: FloatArray
    x_m: FloatArray  # UTM easting; NaN where it could not be placed
    y_m: FloatArray
    distance_m: FloatArray
    confidence_pct: FloatArray
    depth_m: FloatArray  # below the water surface: the distance plus the draft
    reason: npt.NDArray[np.int8]  # qc.Reason
    segment: IntArray  # one pass of one source without a gap
    crs: CRS
    track_x: FloatArray  # the fixes kept (positions), time order, for the line spacing
    track_y: FloatArray
    track_segment: IntArray

    @property
    def kept(self) -> npt.NDArray[np.bool_]:
        result: npt.NDArray[np.bool_] = self.reason == qc.Reason.KEPT
        return result

    def counts(self) -> dict[str, int]:
        return qc.counts(self.reason)

    def of(self, source: int) -> dict[str, int]:
        return qc.counts(self.reason[self.source == source])


def utm_crs(lat: float, lon: float) -> CRS:
    """The WGS 84 UTM zone's CRS at (lat, lon), as pyproj's database gives it."""
    from pyproj import CRS
    from pyproj.aoi import AreaOfInterest
    from pyproj.database import query_utm_crs_info

    found = query_utm_crs_info(
        datum_name="WGS 84", area_of_interest=AreaOfInterest(lon, lat, lon, lat)
    )
    if not found:
        raise ValueError(f"no UTM zone for {lat:g}, {lon:g}")
    return CRS.from_epsg(int(found[0].code))


def _segments(session: IntArray, mono_s: FloatArray, max_gap_s: float) -> IntArray:
    """A new segment at each change of session and each gap over `max_gap_s` (time order)."""
    if len(mono_s) == 0:
        return np.zeros(0, dtype=np.int64)
    new = (session[1:] != session[:-1]) | (np.diff(mono_s) > max_gap_s)
    return np.concatenate([[0], np.cumsum(new)]).astype(np.int64)


def _fix_arrays(fixes: list[FixRecord]) -> dict[str, FloatArray]:
    return {
        "session": np.array([-1 if f.session_id is None else f.session_id for f in fixes]),
        "mono": np.array([f.mono_s for f in fixes], dtype=np.float64),
        "wall": np.array([f.wall_s for f in fixes], dtype=np.float64),
        "lat": np.array([f.lat_deg for f in fixes], dtype=np.float64),
        "lon": np.array([f.lon_deg for f in fixes], dtype=np.float64),
        "distance": np.array([f.sonar_distance_m for f in fixes], dtype=np.float64),
        "confidence": np.array([f.sonar_confidence_pct for f in fixes], dtype=np.float64),
    }


def _place(
    fix_session: IntArray,
    fix_mono: FloatArray,
    fix_x: FloatArray,
    fix_y: FloatArray,
    session: IntArray,
    mono: FloatArray,
    max_gap_s: float,
) -> tuple[FloatArray, FloatArray]:
    """Each reading's position interpolated between the fixes of its session around it,
    NaN where they are more than `max_gap_s` apart or there is none on one side."""
    x = np.full(len(mono), np.nan)
    y = np.full(len(mono), np.nan)
    for s in np.unique(session):
        fixes = np.flatnonzero(fix_session == s)
        readings = np.flatnonzero(session == s)
        if len(fixes) < 2 or len(readings) == 0:
            continue
        order = fixes[np.argsort(fix_mono[fixes], kind="stable")]
        t = fix_mono[order]
        at = mono[readings]
        after = np.searchsorted(t, at, side="left")
        after = np.clip(after, 1, len(t) - 1)
        before = after - 1
        t0, t1 = t[before], t[after]
        ok = (at >= t0) & (at <= t1) & (t1 - t0 <= max_gap_s)
        w = np.where(t1 > t0, (at - t0) / np.where(t1 > t0, t1 - t0, 1.0), 0.0)
        px = fix_x[order[before]] + w * (fix_x[order[after]] - fix_x[order[before]])
        py = fix_y[order[before]] + w * (fix_y[order[after]] - fix_y[order[before]])
        x[readings[ok]] = px[ok]
        y[readings[ok]] = py[ok]
    return x, y


def soundings(
    fixes: list[FixRecord], readings: list[SonarReadingRecord], settings: SurveySettings
) -> Soundings:
    """The soundings of `fixes` and `readings` (one survey's), corrected and judged."""
    from pyproj import Transformer

    if not fixes:
        raise ValueError("no fixes: nothing to place a sounding at")
    f = _fix_arrays(fixes)
    crs = utm_crs(float(np.median(f["lat"])), float(np.median(f["lon"])))
    to_utm = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    fx, fy = (np.asarray(v, dtype=np.float64) for v in to_utm.transform(f["lon"], f["lat"]))
    order = np.lexsort((f["mono"], f["session"]))
    f = {k: v[order] for k, v in f.items()}
    fx, fy = fx[order], fy[order]
    fix_segment = _segments(f["session"].astype(np.int64), f["mono"], settings.max_gap_s)
    jumped = qc.position_jumps(f["mono"], fx, fy, fix_segment, max_speed_m_s=settings.max_speed_m_s)
    fix_valid = (f["confidence"] <= 100) & (f["distance"] < 1000.0)
    fix_reason = qc.screen(
        f["distance"], f["confidence"], fix_valid, min_confidence_pct=settings.min_confidence_pct
    )
    fix_reason[(fix_reason == qc.Reason.KEPT) & jumped] = qc.Reason.POSITION_JUMP
    good = ~jumped
    # The Ping1D's readings, placed on the track of the fixes that are not glitches.
    r_session = np.array([-1 if r.session_id is None else r.session_id for r in readings])
    r_mono = np.array([r.mono_s for r in readings], dtype=np.float64)
    rx, ry = _place(
        f["session"][good].astype(np.int64), f["mono"][good], fx[good], fy[good],
        r_session.astype(np.int64), r_mono, settings.max_gap_s,
    )  # fmt: skip
    r_distance = np.array([r.distance_mm / 1000.0 for r in readings], dtype=np.float64)
    r_confidence = np.array([r.confidence_pct for r in readings], dtype=np.float64)
    r_valid = np.array([r.valid for r in readings], dtype=bool)
    r_reason = qc.screen(
        r_distance, r_confidence, r_valid, min_confidence_pct=settings.min_confidence_pct
    )
    r_reason[(r_reason == qc.Reason.KEPT) & np.isnan(rx)] = qc.Reason.OFF_TRACK
    r_segment = _segments(r_session.astype(np.int64), r_mono, settings.max_gap_s)
    source = np.concatenate([np.zeros(len(fx), np.int8), np.ones(len(rx), np.int8)])
    distance = np.concatenate([f["distance"], r_distance])
    draft = np.where(source == AUTOPILOT, settings.autopilot_draft_m, settings.onboard_draft_m)
    depth = distance + draft
    reason = np.concatenate([fix_reason, r_reason])
    segment = np.concatenate([fix_segment, r_segment + _SEGMENT_STRIDE])
    candidates = np.flatnonzero(reason == qc.Reason.KEPT)
    spiked = qc.spikes(depth[candidates], segment[candidates])
    reason[candidates[spiked]] = qc.Reason.SPIKE
    return Soundings(
        source=source,
        session=np.concatenate([f["session"], r_session]).astype(np.int64),
        mono_s=np.concatenate([f["mono"], r_mono]),
        wall_s=np.concatenate([f["wall"], [r.wall_s for r in readings]]).astype(np.float64),
        x_m=np.concatenate([fx, rx]),
        y_m=np.concatenate([fy, ry]),
        distance_m=distance,
        confidence_pct=np.concatenate([f["confidence"], r_confidence]),
        depth_m=depth,
        reason=reason,
        segment=segment,
        crs=crs,
        track_x=fx[good],
        track_y=fy[good],
        track_segment=fix_segment[good],
    )
