"""The map's summary: what a field team reads first, as text and as JSON.

This module owns the summary of a survey's map: the area mapped, the deepest and
mean depth, the volume, the soundings used and rejected (by reason, by source),
the cross-validated RMSE and bias (an estimate, said as one), the rules the grid
was made by, and SIMULATED when it was. The same figures go into `summary.json`
for programs. It never reads the journal.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cc_daemon.export.bathymap import SurveyMap
from cc_daemon.export.soundings import SOURCES
from cc_daemon.store.records import iso_utc


def figures(survey_map: SurveyMap) -> dict[str, Any]:
    bed, grid = survey_map.bed, survey_map.bed.grid
    mapped = grid.depth_m[grid.mapped]
    hyps = bed.hypsography
    found = survey_map.soundings
    return {
        "survey": survey_map.survey.id,
        "simulated": survey_map.simulated,
        "start_utc": iso_utc(survey_map.survey.start_wall_s),
        "end_utc": iso_utc(survey_map.survey.end_wall_s),
        "crs": f"EPSG:{survey_map.epsg}",
        "area_mapped_m2": grid.mapped_area_m2,
        "covered_fraction": round(grid.covered_fraction, 4),
        "max_depth_m": float(mapped.max()) if len(mapped) else None,
        "mean_depth_m": float(mapped.mean()) if len(mapped) else None,
        "volume_m3": float(hyps.volume_m3[0]) if hyps is not None else None,
        "soundings": found.counts(),
        "soundings_by_source": {name: found.of(i) for i, name in enumerate(SOURCES)},
        "cv_rmse_m": bed.cv.rmse_m,
        "cv_bias_m": bed.cv.bias_m,
        "cv_raw_rmse_m": bed.cv.raw_rmse_m,
        "cv_predicted": bed.cv.predicted,
        "line_spacing_m": bed.spacing_m,
        "cell_m": bed.cell_m,
        "max_distance_m": bed.max_distance_m,
        "interpolation": bed.method,
        "water_level_m": survey_map.options.water_level_m,
    }


def text(survey_map: SurveyMap) -> str:
    """The summary as lines of text."""
    f = figures(survey_map)
    counts = dict(f["soundings"])
    kept = counts.pop("kept")
    rejected = sum(counts.values())
    reasons = ", ".join(f"{n} {why.replace('_', ' ')}" for why, n in counts.items() if n)
    spacing = (
        f"{f['line_spacing_m']:.1f} m (from the track)"
        if f["line_spacing_m"] is not None
        else "not found (no second pass): the 20 m rules used"
    )
    deep = "-" if f["max_depth_m"] is None else f"{f['max_depth_m']:.2f} m"
    mean = "-" if f["mean_depth_m"] is None else f"{f['mean_depth_m']:.2f} m"
    volume = "-" if f["volume_m3"] is None else f"{f['volume_m3']:,.0f} m³"
    lines = [
        f"{'SIMULATED ' if f['simulated'] else ''}survey {f['survey']}: "
        f"{f['start_utc'][:19]}Z to {f['end_utc'][:19]}Z, {f['crs']}",
        f"area mapped      {f['area_mapped_m2']:,.0f} m² ({f['covered_fraction']:.0%} of the"
        " survey's outline)",
        f"depth            deepest {deep}, mean {mean}",
        f"volume           {volume} (of the water over the mapped area)",
        f"soundings        {kept} used, {rejected} rejected" + (f": {reasons}" if reasons else ""),
        f"accuracy         {accuracy(survey_map)}",
        f"grid             {f['cell_m']:g} m cells, {f['interpolation']} interpolation, empty"
        f" beyond {f['max_distance_m']:.1f} m of a sounding; line spacing {spacing}",
    ]
    if f["water_level_m"] is not None:
        lines.append(f"water level      {f['water_level_m']:g} m above sea level")
    return "\n".join(lines) + "\n"


def accuracy(survey_map: SurveyMap) -> str:
    """The cross-validated RMSE and bias, said as an estimate, or why there is none."""
    cv = survey_map.bed.cv
    if not np.isfinite(cv.rmse_m):
        return (
            f"not estimated: {cv.predicted} held-out blocks could be predicted, too few"
            " (a survey of a few lines)"
        )
    return (
        f"cross-validated RMSE {cv.rmse_m:.3f} m, bias {cv.bias_m:+.3f} m (an estimate:"
        f" {cv.predicted} held-out blocks)"
    )


def finite(value: Any) -> Any:
    """JSON has no NaN: None in its place, everywhere in `value`."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value
