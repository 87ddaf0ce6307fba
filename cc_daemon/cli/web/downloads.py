"""A survey as the files `cc-daemon export` writes: CSV samples, GeoJSON, NetCDF-CF.

The same writers as the command, fed by a read-only `JournalReader`; each file
is made whole in memory (or a temporary file, for NetCDF) before a byte is sent.
"""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

from cc_daemon.cli.web.journaldata import NotFound
from cc_daemon.store import JournalReader, StoreError

FORMATS = {
    "csv": "text/csv; charset=utf-8",
    "geojson": "application/geo+json",
    "nc": "application/x-netcdf",
}


def survey_file(path: Path, survey: int, fmt: str) -> bytes:
    """The survey's file in `fmt` (a key of FORMATS). NotFound, StoreError, or
    OptionalDependencyError (netCDF4 missing) say why not."""
    from cc_daemon.export import csv, geojson
    from cc_daemon.export.provenance import of_casts

    if not path.exists():
        raise StoreError(f"no journal at {path} yet")
    with JournalReader(path) as reader:
        try:
            reader.select_survey(survey)
        except StoreError as exc:
            raise NotFound(str(exc)) from None
        casts = reader.casts()
        if fmt == "geojson":
            text = io.StringIO()
            geojson.write(casts, reader.fixes(), text)
            return text.getvalue().encode()
        samples = reader.samples()
    if fmt == "csv":
        text = io.StringIO(newline="")
        csv.write_samples(samples, text, provenance=of_casts(casts).comment())
        return text.getvalue().encode()
    from cc_daemon.export import netcdf

    with tempfile.TemporaryDirectory(prefix="cc-daemon-web-") as tmp:
        target = Path(tmp) / "survey.nc"
        netcdf.write(casts, samples, target)
        return target.read_bytes()
