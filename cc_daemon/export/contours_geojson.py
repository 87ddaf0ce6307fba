"""Contour lines of the lake floor as GeoJSON (RFC 7946): WGS 84 longitude, latitude.

This module owns the contours' file: a FeatureCollection with one MultiLineString
feature per depth (`depth_m`, metres below the water surface of the survey's day,
and `simulated`), its lines projected back from the grid's UTM zone to WGS 84 and
written to 1e-7 degree (about a centimetre). RFC 7946 takes no `crs` member: WGS
84 is the format's only CRS. It never reads the journal.
"""

from __future__ import annotations

import json
from typing import Any, TextIO

import numpy as np

from cc_daemon.export.bathymap import SurveyMap
from cc_daemon.science.bathymetry.contours import Contour, contours, interval_m


def map_contours(survey_map: SurveyMap, interval: float | None = None) -> list[Contour]:
    """The map's contour lines, every `interval` metres (by default about eight levels)."""
    grid = survey_map.bed.grid
    step = interval or interval_m(grid.depth_m)
    return contours(grid.spec.x, grid.spec.y, grid.depth_m, step)


def feature_collection(survey_map: SurveyMap, found: list[Contour]) -> dict[str, Any]:
    from pyproj import Transformer

    back = Transformer.from_crs(survey_map.soundings.crs, "EPSG:4326", always_xy=True)
    features = []
    for contour in found:
        lines = []
        for line in contour.lines:
            lon, lat = back.transform(line[:, 0], line[:, 1])
            lines.append(
                [[round(float(a), 7), round(float(b), 7)] for a, b in zip(lon, lat, strict=True)]
            )
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "MultiLineString", "coordinates": lines},
                "properties": {
                    "depth_m": contour.level_m,
                    "simulated": survey_map.simulated,
                },
            }
        )
    return {"type": "FeatureCollection", "features": features}


def write(survey_map: SurveyMap, found: list[Contour], out: TextIO) -> int:
    """Write the contours as GeoJSON to `out`; return how many depths have lines."""
    doc = feature_collection(survey_map, found)
    json.dump(doc, out, separators=(",", ":"), allow_nan=False)
    out.write("\n")
    return len(doc["features"])


def bbox(doc: dict[str, Any]) -> tuple[float, float, float, float] | None:
    """West, south, east, north of every line (None for none)."""
    points = [p for f in doc["features"] for line in f["geometry"]["coordinates"] for p in line]
    if not points:
        return None
    a = np.asarray(points)
    return float(a[:, 0].min()), float(a[:, 1].min()), float(a[:, 0].max()), float(a[:, 1].max())
