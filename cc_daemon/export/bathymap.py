"""A survey's map of the lake floor, from the journal: what `cc-daemon map` writes out.

This module owns the way from one survey in the journal to its `SurveyMap`: the
soundings (`export.soundings`: placed, corrected, judged), the bed mapped from
those kept (`science.bathymetry.bed`), the stations, whether the data were
simulated, and the water level of the day if given. The products are written by
their own modules (`bathy_netcdf`, `geotiff`, `contours_geojson`, `bathy_csv`,
`bathyplot`, `mapsummary`); `survey_hypsography` gives the hypsography alone, for
whoever needs a lake's areas and volumes (Schmidt stability).

It reads the journal only through `JournalReader`, and never writes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from cc_daemon.config.survey import SurveySettings
from cc_daemon.export.soundings import Soundings, soundings
from cc_daemon.science.bathymetry import interpolate
from cc_daemon.science.bathymetry.bed import BedMap, map_bed
from cc_daemon.science.hypsography import Hypsography
from cc_daemon.store import JournalReader
from cc_daemon.store.records import CastRecord, FixRecord
from cc_daemon.store.sonar import SonarReadingRecord
from cc_daemon.store.stations import names
from cc_daemon.store.surveys import SurveyRecord


@dataclass(frozen=True, slots=True)
class MapOptions:
    """What the command line may set; None: the rules' choice (docs/maps.md)."""

    survey: SurveySettings = field(default_factory=SurveySettings)
    cell_m: float | None = None
    max_distance_m: float | None = None
    method: str = interpolate.DEFAULT
    interval_m: float | None = None  # the hypsography's
    water_level_m: float | None = None  # metres above sea level, of the survey's day


@dataclass(frozen=True, slots=True)
class SurveyMap:
    survey: SurveyRecord
    soundings: Soundings
    bed: BedMap
    casts: list[CastRecord]
    fixes: list[FixRecord]
    options: MapOptions
    source_file: Path
    station_names: dict[int, str] = field(default_factory=dict)  # cast id: S1...

    @property
    def simulated(self) -> bool:
        return bool(self.survey.simulated)

    @property
    def epsg(self) -> int:
        code = self.soundings.crs.to_epsg()
        return int(code) if code is not None else 0

    def elevation_m(self) -> npt.NDArray[np.float64] | None:
        """The bed's elevation above sea level, with a water level; else None."""
        level = self.options.water_level_m
        return None if level is None else level - self.bed.grid.depth_m


def read_survey(
    reader: JournalReader,
) -> tuple[list[FixRecord], list[CastRecord], list[SonarReadingRecord]]:
    """The fixes, casts and Ping1D readings of the reader's survey."""
    fixes = reader.fixes()
    casts = reader.casts()
    readings: list[SonarReadingRecord] = []
    if fixes:
        readings = reader.sonar_readings(
            since=fixes[0].wall_s - 60.0, until=fixes[-1].wall_s + 60.0, session=reader.survey
        )
    return fixes, casts, readings


def make_map(reader: JournalReader, survey: SurveyRecord, options: MapOptions) -> SurveyMap:
    """The map of `survey` (the reader narrowed to it). ValueError when it cannot be made
    (no fixes, too few soundings kept, all on one line), saying why."""
    fixes, casts, readings = read_survey(reader)
    found = soundings(fixes, readings, options.survey)
    kept = found.kept
    if not kept.any():
        counts = ", ".join(f"{n} {why}" for why, n in found.counts().items() if n)
        raise ValueError(f"no sounding kept of {len(kept)} ({counts}): nothing to map")
    bed = map_bed(
        found.x_m[kept],
        found.y_m[kept],
        found.depth_m[kept],
        track_x=found.track_x,
        track_y=found.track_y,
        track_segment=found.track_segment,
        cell_m=options.cell_m,
        max_distance_m=options.max_distance_m,
        method=options.method,
        hypsography_interval_m=options.interval_m,
    )
    named = names(reader.stations())
    return SurveyMap(survey, found, bed, casts, fixes, options, reader.path, named)


def survey_hypsography(
    db: Path, survey: int, *, options: MapOptions | None = None
) -> tuple[Hypsography | None, str]:
    """Survey `survey`'s hypsography from journal `db`, mapped as `cc-daemon map` maps
    it; (None, why) when it cannot be made (no such survey, no soundings, none mapped)
    or cannot be trusted: a map whose accuracy could not be estimated (a few lines
    between stations) is a sketch, and Schmidt stability read from it would overstate."""
    from cc_daemon.store import StoreError

    try:
        with JournalReader(db) as reader:
            chosen = reader.select_survey(survey)
            if chosen is None:
                return None, f"no survey {survey} in {db}"
            made = make_map(reader, chosen, options or MapOptions())
    except (StoreError, ValueError) as exc:
        return None, str(exc)
    return trusted_hypsography(made)


def trusted_hypsography(made: SurveyMap) -> tuple[Hypsography | None, str]:
    """The map's hypsography, or (None, why) when no cell was mapped or the map is a
    sketch whose accuracy could not be estimated (Schmidt stability would overstate)."""
    survey = made.survey.id
    if made.bed.hypsography is None:
        return None, f"survey {survey}: no cell of the grid was mapped"
    if math.isnan(made.bed.cv.rmse_m):
        return None, (
            f"survey {survey}: its soundings map too little of the lake to trust (the map's"
            f" accuracy could not be estimated: {made.bed.cv.predicted} held-out blocks)"
        )
    return made.bed.hypsography, ""
