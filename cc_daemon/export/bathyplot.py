"""The lake floor as a map a field team can read: depth, contours, track, stations.

This module owns the PNG map of a survey's bed: the gridded depth in colour with a
colour bar in metres, labelled contour lines (the same levels as the GeoJSON's),
cells not mapped shown as empty (hatched, named in the legend with the maximum
distance), the track of the fixes kept and the stations, equal aspect in metres
(a metre is a metre both ways) with a scale bar, the cross-validated RMSE and bias
in the title, and SIMULATED across the map when the data were. The house style of
`export.plot` and `export.mapframe` (matplotlib, imported when drawing). It never
reads the journal.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cc_daemon.export.bathymap import SurveyMap
from cc_daemon.export.mapframe import figure, place_labels
from cc_daemon.export.mapsummary import accuracy
from cc_daemon.export.plot import DPI
from cc_daemon.science.bathymetry.contours import Contour
from cc_daemon.science.bathymetry.spacing import nice


def scale_bar_m(width_m: float) -> float:
    """A round length about a fifth of the map's width."""
    return nice(max(width_m / 5.0, 1.0))


def map_figure(survey_map: SurveyMap, found: list[Contour]) -> Any:
    """The map's figure (a matplotlib `Figure`), not yet written anywhere."""
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar
    from pyproj import Transformer

    bed, grid = survey_map.bed, survey_map.bed.grid
    spec = grid.spec
    x0, y0 = spec.x0, spec.y0
    width, height = spec.nx * spec.cell_m, spec.ny * spec.cell_m
    fig = figure(9.0, min(max(7.0 * height / max(width, 1.0), 4.0), 11.0) + 1.5)
    ax = fig.add_subplot()
    # Empty cells show the axes behind them: hatched, never a colour of the scale.
    ax.set_facecolor("white")
    ax.add_patch(_hatched(0.0, 0.0, width, height))
    depth = np.ma.masked_invalid(grid.depth_m)
    edges_x = np.arange(spec.nx + 1) * spec.cell_m
    edges_y = np.arange(spec.ny + 1) * spec.cell_m
    mesh = ax.pcolormesh(edges_x, edges_y, depth, cmap="viridis_r", shading="flat", zorder=1)
    fig.colorbar(mesh, ax=ax, label="depth below the water surface (m)", shrink=0.8)
    levels = [c.level_m for c in found]
    if levels and grid.mapped_cells:
        lines = ax.contour(
            spec.x - x0, spec.y - y0, depth, levels=levels, colors="black", linewidths=0.7,
            zorder=2,
        )  # fmt: skip
        ax.clabel(lines, fmt="%g m", fontsize="x-small")
    kept = survey_map.soundings
    ax.plot(kept.track_x - x0, kept.track_y - y0, color="0.15", lw=0.5, alpha=0.6, zorder=3,
            label="track (fixes kept)")  # fmt: skip
    if survey_map.casts:
        to_utm = Transformer.from_crs("EPSG:4326", kept.crs, always_xy=True)
        sx, sy = to_utm.transform(
            [c.lon_deg for c in survey_map.casts], [c.lat_deg for c in survey_map.casts]
        )
        px, py = np.asarray(sx) - x0, np.asarray(sy) - y0
        ax.scatter(px, py, marker="v", s=70, color="crimson", edgecolors="black", zorder=4,
                   label="station")  # fmt: skip
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlim(0, width)
    ax.set_ylim(0, height)
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.yaxis.set_major_locator(MaxNLocator(6))
    ax.ticklabel_format(useOffset=False, style="plain")
    zone = kept.crs.name
    ax.set_xlabel(f"metres east of the grid's south-west corner ({zone}, E {x0:.0f} m)")
    ax.set_ylabel(f"metres north (N {y0:.0f} m)")
    bar = scale_bar_m(width)
    ax.add_artist(
        AnchoredSizeBar(ax.transData, bar, f"{bar:g} m", "lower right", pad=0.5,
                        color="black", frameon=True, size_vertical=height / 150)
    )  # fmt: skip
    simulated = "SIMULATED · " if survey_map.simulated else ""
    ax.set_title(
        f"{simulated}Lake bed, survey {survey_map.survey.id}: {bed.cell_m:g} m cells,"
        f" {bed.method} interpolation\n{accuracy(survey_map).split(' (')[0]}"
        + (" (an estimate)" if np.isfinite(bed.cv.rmse_m) else "")
    )
    handles, _ = ax.get_legend_handles_labels()
    handles.append(
        Patch(facecolor="white", hatch="////", edgecolor="0.6",
              label=f"not mapped (no sounding within {bed.max_distance_m:.0f} m)")
    )  # fmt: skip
    fig.legend(handles=handles, loc="outside lower center", ncols=3, fontsize="small")
    if survey_map.simulated:
        ax.text(0.5, 0.5, "SIMULATED", transform=ax.transAxes, ha="center", va="center",
                fontsize=40, color="crimson", alpha=0.25, rotation=20, zorder=5)  # fmt: skip
    if survey_map.casts:
        place_labels(fig, ax, list(zip(px, py, strict=True)),
                     [survey_map.station_names.get(c.id, f"cast {c.id}") for c in survey_map.casts],
                     fontsize="x-small")  # fmt: skip
    return fig


def _hatched(x: float, y: float, width: float, height: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle(
        (x, y), width, height, fill=False, hatch="////", edgecolor="0.75", lw=0, zorder=0
    )


def write(survey_map: SurveyMap, found: list[Contour], path: Path) -> None:
    map_figure(survey_map, found).savefig(path, dpi=DPI, format="png")
