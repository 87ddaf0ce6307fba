"""The files a survey is taken home as, made from an open journal reader: one function
per file, for `cc-daemon export`, `cc-daemon sonde export` and the field page's
downloads alike, so the page's file is the command's, byte for byte.

Each gathers what its writer needs beyond the rows (the winch's provenance, which
depths are estimates, the stations' names, the sonde's register map) and hands it
to the writer in `cc_daemon.export`. It reads through the reader it is given and
never opens or changes a journal itself.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TextIO

from cc_daemon.store import JournalReader
from cc_daemon.store.reader import DamagedJournalError
from cc_daemon.store.records import CastRecord, SampleRecord
from cc_daemon.store.stations import names


def samples_csv(
    reader: JournalReader,
    casts: Sequence[CastRecord],
    samples: Iterable[SampleRecord],
    out: TextIO,
) -> int:
    """The winch's depth samples of `casts` as CSV (`export.csv.write_samples`)."""
    from cc_daemon.export import csv, estimates
    from cc_daemon.export.provenance import of_casts

    return csv.write_samples(
        samples,
        out,
        provenance=of_casts(casts).comment(),
        estimates=estimates.of_casts(casts, reader.events()),
        stations=names(reader.stations()),
    )


def sonde_csv(reader: JournalReader, cast_id: int | None, out: TextIO) -> int:
    """The sonde's readings (of cast `cast_id`, else of the reader's survey) as CSV."""
    from cc_daemon.export import sonde

    casts = reader.casts(cast_id=cast_id)
    samples = reader.sonde_samples(cast_id=cast_id)
    columns = sonde.parameter_map(reader.events(), samples)
    _undamaged(reader)
    return sonde.write_csv(samples, columns, casts, out)


def sonde_netcdf(reader: JournalReader, cast_id: int | None, path: Path) -> tuple[int, int]:
    """The sonde's readings as CF profiles in NetCDF: (readings, profiles) written.
    OptionalDependencyError without netCDF4; ValueError with no reading to write."""
    from cc_daemon.export import sonde, sonde_netcdf

    casts = reader.casts(cast_id=cast_id)
    samples = reader.sonde_samples(cast_id=cast_id)
    columns = sonde.parameter_map(reader.events(), samples)
    _undamaged(reader)
    return sonde_netcdf.write(casts, samples, columns, path), len(casts)


def _undamaged(reader: JournalReader) -> None:
    """A file read from a damaged journal is not begun: the damage is said instead, in
    one line, before its first byte (`cc-daemon recover` saves what can be)."""
    damage = reader.damage_report()
    if damage is not None:
        raise DamagedJournalError(damage)
