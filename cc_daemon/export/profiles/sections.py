"""A parameter along the survey against depth, contoured from the binned ways down.

This module owns the section figure of `cc-daemon profiles`: x is the distance
along the survey (metres, station to station in cast order), y the depth
(increasing downwards); the binned values of the ways down are contoured
between the stations (filled, with a colour bar in the parameter's unit), each
station is a vertical tick with its cast number, and everything below the bed
(the sonar bottom each cast was planned on, joined straight between stations)
is masked out by the bed itself, drawn brown. A station cast blind has no known
bed: the mask stops at its neighbours. It needs two stations at different
places with values; with fewer it says so (ValueError). matplotlib on Agg; it
never reads the journal.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cc_daemon.export.mapframe import figure, shown
from cc_daemon.export.profiles.survey import ProfiledCast, Survey
from cc_daemon.export.sonde import Column
from cc_daemon.export.sondeplot import along_track_m

DPI = 120
BED = "#8c6d46"
LEVELS = 14


def stations(survey: Survey) -> list[tuple[float, ProfiledCast]]:
    """The casts along the survey with their distances; a cast at the place of the one
    before (a repeated station) replaces it."""
    distances = along_track_m([c.cast for c in survey.casts])
    placed: list[tuple[float, ProfiledCast]] = []
    for distance, cast in zip(distances, survey.casts, strict=True):
        if placed and distance - placed[-1][0] < 0.5:
            placed[-1] = (placed[-1][0], cast)
        else:
            placed.append((distance, cast))
    return placed


def section_figure(survey: Survey, column: Column) -> Any:
    placed = [
        (d, c) for d, c in stations(survey) if (c.processed.down.count[column.name] > 0).any()
    ]
    if len(placed) < 2:
        raise ValueError(f"a section of {column.name} needs two stations with its values")
    x = np.array([d for d, _ in placed])
    depth = placed[0][1].processed.down.depth_m
    grid = np.array([c.processed.down.value[column.name] for _, c in placed]).T
    values = np.ma.masked_invalid(grid)
    fig = figure(9.0, 4.8)
    ax = fig.add_subplot()
    filled = ax.contourf(x, depth, values, levels=LEVELS, cmap="viridis")
    unit = f" [{shown(column.unit)}]" if column.unit else ""
    fig.colorbar(filled, ax=ax, label=f"{shown(column.long_name)}{unit}")
    bed = np.array([np.nan if c.bed_m is None else c.bed_m for _, c in placed])
    reached = max(float(np.nanmax(depth[np.isfinite(values).any(axis=1)])), 0.5)
    bottom = max(reached, float(np.nanmax(bed)) if np.isfinite(bed).any() else reached) * 1.08
    known = np.isfinite(bed)
    if known.any():
        ax.fill_between(x, np.where(known, bed, np.nan), bottom, color=BED, label="below the bed")
        ax.plot(x[known], bed[known], color="black", lw=1.0)
    for distance, cast in placed:
        ax.axvline(distance, color="white", lw=0.6, alpha=0.7)
        ax.annotate(str(cast.cast.id), (distance, 0.0), fontsize=7, ha="center",
                    xytext=(0, 4), textcoords="offset points", annotation_clip=False)  # fmt: skip
    ax.set_ylim(bottom, 0.0)
    ax.set_xlim(x[0], x[-1])
    ax.set_xlabel("distance along the survey [m] (stations numbered by cast)")
    ax.set_ylabel("depth [m]")
    if known.any():
        ax.legend(loc="lower right", fontsize=7)
    simulated = " - SIMULATED" if survey.simulated else ""
    ax.set_title(
        f"{shown(column.name)} along the survey, binned way down "
        f"({survey.settings.bin_m:g} m bins){simulated}",
        pad=14,
    )
    return fig


def plot_section(survey: Survey, column: Column, path: Path) -> None:
    section_figure(survey, column).savefig(str(path), dpi=DPI)
