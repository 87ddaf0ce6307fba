"""CSV exports of the journal: samples, telemetry fixes and events.

This module owns the columns and number formats of the CSV files: one row per
record, a header row, RFC 4180 quoting (the `csv` module's default dialect),
times as ISO 8601 UTC, positions in degrees to 1e-7 (the autopilot's own
resolution), depths and distances in metres to the millimetre. It never reads
the journal and never reorders or filters what it is given.

Every time column comes with `clock_synced` (0: the Pi's clock had not been
synchronised, so the UTC time may be wrong) and `monotonic_s`, which is exact
within one boot and lets the data be re-timed later.

Every CSV the project writes goes through `writer`, which neutralises formulas
(OWASP's rule against CSV injection): a text cell that starts with `=`, `+`,
`-`, `@`, a tab or a carriage return, and is not a plain number, gets a `'` in
front, so a spreadsheet shows `=HYPERLINK(...)` from a stranger's journal as
text instead of running it. Numbers (`-3.7233962`) stay numbers.
"""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Iterable, Mapping
from typing import Any, Protocol, TextIO

from cc_daemon.export.estimates import Estimate, for_samples
from cc_daemon.store.records import EventRecord, FixRecord, SampleRecord, iso_utc
from cc_daemon.store.sonar import SonarReadingRecord

SAMPLE_COLUMNS = (
    "cast_id",
    "station",
    "time_utc",
    "lat",
    "lon",
    "depth_m",
    "depth_low_m",
    "depth_high_m",
    "phase",
    "clock_synced",
    "monotonic_s",
)
FIX_COLUMNS = (
    "time_utc",
    "lat",
    "lon",
    "alt_m",
    "sonar_depth_m",
    "sonar_confidence_pct",
    "frame",
    "autopilot_timestamp_s",
    "autopilot_byte_order",
    "clock_synced",
    "monotonic_s",
)
EVENT_COLUMNS = ("time_utc", "kind", "detail", "clock_synced", "monotonic_s")
SONAR_COLUMNS = (
    "time_utc", "port", "distance_m", "confidence_pct", "valid", "clock_synced", "monotonic_s",
)  # fmt: skip


_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?\Z")


def neutral(cell: Any) -> Any:
    """`cell` as a spreadsheet may safely open it: a text that would start a formula gets
    a `'` in front; numbers (and text that is a plain number) are left as they are."""
    if isinstance(cell, str) and cell.startswith(_FORMULA_START) and not _NUMBER.match(cell):
        return "'" + cell
    return cell


class RowWriter(Protocol):
    def writerow(self, row: Iterable[Any]) -> Any: ...


class _Neutralising:
    def __init__(self, out: TextIO) -> None:
        self._writer = csv.writer(out)

    def writerow(self, row: Iterable[Any]) -> Any:
        return self._writer.writerow([neutral(cell) for cell in row])


def writer(out: TextIO) -> RowWriter:
    """A `csv.writer` (RFC 4180 quoting) whose every cell goes through `neutral`."""
    return _Neutralising(out)


def comment(text: str) -> str:
    """A `#` comment line's text, on one line whatever the journal held (no row can
    be slipped in after it)."""
    return "".join(c if c.isprintable() else " " for c in text)


def _deg(value: float | None) -> str:
    return "" if value is None else f"{value:.7f}"


def write_samples(
    samples: Iterable[SampleRecord],
    out: TextIO,
    *,
    provenance: str | None = None,
    estimates: Mapping[int, Estimate] | None = None,
    stations: Mapping[int, str] | None = None,
) -> int:
    """One row per depth sample; returns the number of rows written. `provenance`
    (the winch and whether it was simulated) goes first, as a `#` comment line.

    `depth_low_m` and `depth_high_m` are empty for a measured depth; for an
    estimate (`export.estimates`: the count was in doubt) they give the range the
    probe was in, and `depth_m` is the best estimate. `station` is the cast's
    station as `store.stations` names it (S1, S2...)."""
    if provenance is not None:
        out.write(comment(provenance) + "\r\n")
    rows = writer(out)
    rows.writerow(SAMPLE_COLUMNS)
    count = 0
    names = stations or {}
    for s, doubt in for_samples(samples, estimates or {}):
        low, high = ("", "") if doubt is None else (f"{doubt[0]:.3f}", f"{doubt[1]:.3f}")
        rows.writerow(
            (
                s.cast_id,
                names.get(s.cast_id, ""),
                iso_utc(s.wall_s),
                _deg(s.lat_deg),
                _deg(s.lon_deg),
                f"{s.depth_m:.3f}",
                low,
                high,
                s.phase,
                int(s.clock_synced),
                f"{s.mono_s:.3f}",
            )
        )
        count += 1
    return count


def write_fixes(fixes: Iterable[FixRecord], out: TextIO) -> int:
    """One row per telemetry fix (`P-T`) or start-measuring frame (`P-M`)."""
    rows = writer(out)
    rows.writerow(FIX_COLUMNS)
    count = 0
    for f in fixes:
        rows.writerow(
            (
                iso_utc(f.wall_s),
                _deg(f.lat_deg),
                _deg(f.lon_deg),
                f"{f.alt_m:.3f}",
                f"{f.sonar_distance_m:.3f}",
                f.sonar_confidence_pct,
                f.frame,
                f.ap_timestamp_s if f.ap_time_s is None else f.ap_time_s,
                f.ap_time_order or "",
                int(f.clock_synced),
                f"{f.mono_s:.3f}",
            )
        )
        count += 1
    return count


def write_events(events: Iterable[EventRecord], out: TextIO) -> int:
    """One row per link or fault event; `detail` is a JSON object."""
    rows = writer(out)
    rows.writerow(EVENT_COLUMNS)
    count = 0
    for e in events:
        rows.writerow(
            (
                iso_utc(e.wall_s),
                e.kind,
                json.dumps(e.detail, sort_keys=True),
                int(e.clock_synced),
                f"{e.mono_s:.3f}",
            )
        )
        count += 1
    return count


def write_sonar(readings: Iterable[SonarReadingRecord], out: TextIO) -> int:
    """One row per journaled reading of the daemon's own Ping1D, as it arrived.

    `valid` is 0 for a reading that cannot be true (confidence above 100, a
    distance of 1 km or more): its values are written as they came, never mended.
    """
    rows = writer(out)
    rows.writerow(SONAR_COLUMNS)
    count = 0
    for r in readings:
        rows.writerow(
            (
                iso_utc(r.wall_s),
                r.port,
                f"{r.distance_mm / 1000:.3f}",
                r.confidence_pct,
                int(r.valid),
                int(r.clock_synced),
                f"{r.mono_s:.3f}",
            )
        )
        count += 1
    return count
