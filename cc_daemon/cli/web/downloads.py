"""A survey as the files `cc-daemon export` writes: CSV samples, GeoJSON, NetCDF-CF.

The same writers as the command, fed by a read-only `JournalReader`, writing to
a `pipe.Pipe` on a download's own thread, so a download holds a few chunks of
the file at a time, whatever the survey's length (a ten-day survey's GeoJSON is
over 200 MB): the samples are read a cast at a time, the fixes a batch at a
time. NetCDF's profiles need every sample at once (about 80,000 in ten days);
its file is written to a temporary directory, sent from there, and removed
however the download ends. Everything that can refuse a download (no such
survey, a damaged journal, no netCDF4, no cast) does so before its first byte.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

from cc_daemon.cli import exportfiles
from cc_daemon.cli.web import journaldata
from cc_daemon.cli.web.pipe import CHUNK, Pipe
from cc_daemon.store import CastRecord, JournalReader, SampleRecord

FORMATS = {
    "csv": "text/csv; charset=utf-8",
    "geojson": "application/geo+json",
    "nc": "application/x-netcdf",
    # The sonde's readings: `cc-daemon sonde export --format csv|netcdf`.
    "sonde.csv": "text/csv; charset=utf-8",
    "sonde.nc": "application/x-netcdf",
}
FIX_BATCH = 500  # fixes in memory at once, with their features and text: about 2 MB


def writer(path: Path, survey: int, fmt: str) -> Callable[[Pipe], None]:
    """What writes survey `survey` as `fmt` (a key of FORMATS) to a pipe. It raises
    NotFound, StoreError, OptionalDependencyError (netCDF4 missing) or ValueError
    (NetCDF of a survey without a cast) before it writes anything."""
    makers = {
        "csv": _csv,
        "geojson": _geojson,
        "nc": _netcdf,
        "sonde.csv": _sonde_csv,
        "sonde.nc": _sonde_netcdf,
    }
    return makers[fmt](path, survey)


def _chosen(reader: JournalReader, survey: int) -> list[CastRecord]:
    journaldata.undamaged_survey(reader, survey)  # said before the first byte, not after
    return reader.casts()


def _csv(path: Path, survey: int) -> Callable[[Pipe], None]:
    def write(out: Pipe) -> None:
        with journaldata._open(path) as reader:
            casts = _chosen(reader, survey)
            samples = (s for cast in casts for s in reader.samples(cast_id=cast.id))
            exportfiles.samples_csv(reader, casts, samples, out.as_text())

    return write


def _sonde_csv(path: Path, survey: int) -> Callable[[Pipe], None]:
    def write(out: Pipe) -> None:
        with journaldata._open(path) as reader:
            _chosen(reader, survey)
            exportfiles.sonde_csv(reader, None, out.as_text())

    return write


def _sonde_netcdf(path: Path, survey: int) -> Callable[[Pipe], None]:
    return _from_file(path, survey, lambda reader, target: exportfiles.sonde_netcdf(
        reader, None, target))  # fmt: skip


def _geojson(path: Path, survey: int) -> Callable[[Pipe], None]:
    def write(out: Pipe) -> None:
        from cc_daemon.export import geojson

        with journaldata._open(path) as reader:
            casts = _chosen(reader, survey)
            geojson.write_batches(casts, lambda: reader.fix_batches(FIX_BATCH), out.as_text())

    return write


def _netcdf(path: Path, survey: int) -> Callable[[Pipe], None]:
    def made(reader: JournalReader, target: Path) -> None:
        from cc_daemon.export import netcdf

        casts = reader.casts()
        samples: list[SampleRecord] = reader.samples()
        netcdf.write(casts, samples, target)

    return _from_file(path, survey, made)


def _from_file(
    path: Path, survey: int, make: Callable[[JournalReader, Path], object]
) -> Callable[[Pipe], None]:
    """A file its library writes to a path (NetCDF): made in a temporary directory,
    then sent, and removed however the download ends."""

    def write(out: Pipe) -> None:
        with tempfile.TemporaryDirectory(prefix="cc-daemon-web-") as tmp:
            target = Path(tmp) / "survey.nc"
            with journaldata._open(path) as reader:
                _chosen(reader, survey)
                make(reader, target)
            with target.open("rb") as made:
                while chunk := made.read(CHUNK):
                    out.write_bytes(chunk)

    return write
