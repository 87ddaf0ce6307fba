"""Figures of the survey journal: how fast it writes, how big it grows, how fast it exports.

    python -m benchmarks.journal        (or `make bench`, which runs every benchmark)

- the cost of a `record_*` call on the event loop's thread;
- the rows per second the writer thread sustains into a real file in a
  temporary directory, for telemetry (batched, synchronous=NORMAL) and for
  cast samples (committed at once, synchronous=FULL);
- the file size of a 6-hour survey (1 fix a second, a ~60 s cast with one
  sample a second every 10 minutes), written in fast-forward through the same
  `Journal` API with a fake clock, as bytes per hour;
- the time to export a day of such data to CSV (samples, telemetry) and
  GeoJSON, reading the journal included.
"""

from __future__ import annotations

import io
import platform
import sqlite3
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.export import csv as csv_export
from cc_daemon.export import geojson
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, SurveySummary, write_survey

FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
STATION = StartMeasuring(72, -37260579, 404506308, 702385, 8219, 100)
TELEMETRY_ROWS = 200_000
SAMPLE_ROWS = 50_000
LATENCY_SAMPLES = 50


def _drain(journal: Journal, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while journal.health().pending_rows:
        if time.monotonic() > deadline:
            raise RuntimeError(f"journal did not drain: {journal.health()}")
        time.sleep(0.002)


def _throughput(
    directory: Path, name: str, record: Callable[[Journal, int], None], n: int
) -> tuple[float, float]:
    """(µs per call on the caller's thread, rows per second into the file)."""
    journal = Journal(directory / f"{name}.db", max_buffered_rows=10 * n)
    journal.open()
    try:
        start = time.perf_counter()
        record(journal, n)
        called = time.perf_counter()
        _drain(journal)
        drained = time.perf_counter()
    finally:
        journal.close()
    health = journal.health()
    if health.rows_written < n or health.dropped_rows:
        raise RuntimeError(f"benchmark lost rows: {health}")
    return (called - start) / n * 1e6, n / (drained - start)


def _record_fixes(journal: Journal, n: int) -> None:
    for _ in range(n):
        journal.record_fix(FIX)


def _record_samples(journal: Journal, n: int) -> None:
    cast_id = journal.start_cast(STATION, planned_depth_m=5.0, mode="continuous", plan={})
    for i in range(n - 1):
        journal.record_sample(cast_id, (i % 500) / 100, "descending")


def _commit_latencies(path: Path, n: int) -> list[float]:
    """Milliseconds from `record_sample` returning to its transaction being committed."""
    journal = Journal(path)
    journal.open()
    latencies = []
    try:
        cast_id = journal.start_cast(STATION, planned_depth_m=5.0, mode="continuous", plan={})
        _drain(journal)
        for i in range(n):
            journal.record_sample(cast_id, i / 100, "descending")
            start = time.perf_counter()
            while journal.health().pending_rows:
                time.sleep(0.0002)
            latencies.append((time.perf_counter() - start) * 1e3)
            time.sleep(0.02)
    finally:
        journal.close()
    return latencies


def _survey(path: Path, hours: float) -> tuple[SurveySummary, float]:
    clock = FakeClock()
    journal = Journal(path, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    start = time.perf_counter()
    try:
        summary = write_survey(journal, clock, duration_s=hours * 3600, cast_every_s=600)
    finally:
        journal.close()
    return summary, time.perf_counter() - start


def _timed(action: Callable[[], object]) -> float:
    start = time.perf_counter()
    action()
    return time.perf_counter() - start


def main() -> int:
    print(f"journal: SQLite {sqlite3.sqlite_version}, Python {platform.python_version()}")
    with tempfile.TemporaryDirectory(prefix="cc-daemon-bench-") as tmp:
        directory = Path(tmp)

        fix_us, fix_rate = _throughput(directory, "telemetry", _record_fixes, TELEMETRY_ROWS)
        sample_us, sample_rate = _throughput(directory, "samples", _record_samples, SAMPLE_ROWS)
        print(f"  record_fix call          {fix_us:8.2f} µs  (mean of {TELEMETRY_ROWS:,})")
        print(f"  record_sample call       {sample_us:8.2f} µs  (mean of {SAMPLE_ROWS:,})")
        print(f"  telemetry sustained      {fix_rate:10,.0f} rows/s into the file (need: 1/s)")
        print(
            f"  samples sustained        {sample_rate:10,.0f} rows/s, synchronous=FULL (need: 1/s)"
        )

        latencies = _commit_latencies(directory / "latency.db", LATENCY_SAMPLES)
        print(
            f"  sample durable after     {statistics.median(latencies):8.2f} ms p50,"
            f" {max(latencies):.2f} ms max  (call to FULL commit, {LATENCY_SAMPLES} samples)"
        )

        six = directory / "six-hours.db"
        summary, took = _survey(six, 6.0)
        size = six.stat().st_size
        print(
            f"  6-hour survey            {summary.fixes:,} fixes, {summary.casts} casts,"
            f" {summary.samples:,} samples, {summary.events} events: {size / 1e6:.2f} MB"
            f" = {size / 6 / 1e3:.0f} kB/hour (written in {took:.1f} s)"
        )

        day = directory / "day.db"
        summary, took = _survey(day, 24.0)
        print(
            f"  a day of data            {summary.fixes:,} fixes, {summary.casts} casts,"
            f" {summary.samples:,} samples: {day.stat().st_size / 1e6:.1f} MB"
        )
        sinks = {name: io.StringIO() for name in ("samples", "telemetry", "geojson")}

        def export_samples() -> None:
            with JournalReader(day) as reader:
                csv_export.write_samples(reader.samples(), sinks["samples"])

        def export_telemetry() -> None:
            with JournalReader(day) as reader:
                csv_export.write_fixes(reader.fixes(), sinks["telemetry"])

        def export_geojson() -> None:
            with JournalReader(day) as reader:
                geojson.write(reader.casts(), reader.fixes(), sinks["geojson"])

        for label, action, sink in (
            ("export CSV samples", export_samples, "samples"),
            ("export CSV telemetry", export_telemetry, "telemetry"),
            ("export GeoJSON", export_geojson, "geojson"),
        ):
            seconds = _timed(action)
            megabytes = len(sinks[sink].getvalue().encode()) / 1e6
            print(f"  {label:<24} {seconds:8.2f} s   ({megabytes:.1f} MB, a day of data)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
