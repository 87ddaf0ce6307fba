"""A cast's binned profiles over its raw readings, the thermocline and metalimnion marked.

This module owns the figure `cc-daemon profiles` draws for each cast: one panel per
parameter, the value on x and depth on y (increasing downwards), the raw readings
as the sensors gave them (the way down filled blue dots, the way up open orange
ones, the dwell grey), the binned profiles over them (down: a blue line, up: an
orange dashed one; a bin with too few readings hollow), the thermocline a red
line and the metalimnion a red band with its top and bottom dashed, a panel's
unit on its axis and "SIMULATED" in the title when the sonde was simulated.
Missing values are gaps, never zeros. matplotlib (the `plot` extra) on Agg; it
never reads the journal.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from cc_daemon.export.mapframe import figure, shown
from cc_daemon.export.profiles.survey import ProfiledCast, Survey
from cc_daemon.export.sonde import Column
from cc_daemon.science.profiles.binning import Binned
from cc_daemon.store.records import iso_utc

DPI = 120
DOWN, UP, HELD = "#1f77b4", "#ff7f0e", "#999999"
MARK = "#d62728"


def _label(column: Column) -> str:
    name = shown(column.long_name)
    return f"{name} [{shown(column.unit)}]" if column.unit else name


def _raw(ax: Any, cast: ProfiledCast, name: str) -> None:
    series = cast.series
    values = series.values[name]
    down, up = cast.processed.down_readings, cast.processed.up_readings
    rest = np.setdiff1d(np.arange(len(values)), np.concatenate((down, up)))
    for index, colour, face, label in (
        (down, DOWN, DOWN, "down, as read"),
        (up, UP, "none", "up, as read"),
        (rest, HELD, HELD, "soak, dwell, turns"),
    ):
        ax.plot(values[index], series.depth_m[index], ls="none", marker="o", ms=2.5,
                color=colour, mfc=face, alpha=0.45, label=label)  # fmt: skip


def _binned(ax: Any, profile: Binned, name: str, colour: str, style: str, label: str) -> None:
    held = profile.count[name] > 0
    z, v = profile.depth_m[held], profile.value[name][held]
    few = profile.few[name][held]
    ax.plot(v, z, color=colour, ls=style, lw=1.6, label=label)
    ax.plot(v[~few], z[~few], ls="none", marker="s", ms=4, color=colour)
    ax.plot(v[few], z[few], ls="none", marker="s", ms=4, mfc="white", color=colour)


def _strata(ax: Any, numbers: dict[str, float | None]) -> None:
    top, bottom = numbers.get("metalimnion_top_m"), numbers.get("metalimnion_bottom_m")
    if top is not None and bottom is not None:
        ax.axhspan(top, bottom, color=MARK, alpha=0.08, lw=0)
        ax.axhline(top, color=MARK, ls="--", lw=0.9, label="metalimnion top, bottom")
        ax.axhline(bottom, color=MARK, ls="--", lw=0.9)
    thermocline = numbers.get("thermocline_m")
    if thermocline is not None:
        ax.axhline(thermocline, color=MARK, lw=1.4, label=f"thermocline {thermocline:.2f} m")


def cast_figure(survey: Survey, cast: ProfiledCast) -> Any:
    """The figure of `cast`'s profiles (see the module's docstring)."""
    panels = survey.columns
    if not panels:
        raise ValueError(f"cast {cast.cast.id} has no parameter to plot")
    columns = min(3, len(panels))
    rows = math.ceil(len(panels) / columns)
    fig = figure(3.4 * columns, 3.8 * rows + 0.4)
    axes = fig.subplots(rows, columns, sharey=True, squeeze=False)
    down, up = cast.processed.down, cast.processed.up
    for index, column in enumerate(panels):
        ax = axes[index // columns][index % columns]
        _raw(ax, cast, column.name)
        _binned(ax, down, column.name, DOWN, "-", "down, binned")
        _binned(ax, up, column.name, UP, "--", "up, binned")
        _strata(ax, cast.reading.numbers)
        ax.set_xlabel(_label(column), fontsize=8)
        ax.set_title(shown(column.name), fontsize=9)
        ax.grid(True, alpha=0.3)
        if index % columns == 0:
            ax.set_ylabel("depth [m]")
    for index in range(len(panels), rows * columns):
        axes[index // columns][index % columns].set_visible(False)
    held = np.any([down.count[c.name] > 0 for c in panels], axis=0)
    deepest = max(
        float(np.nanmax(cast.series.depth_m)), float(np.max(down.depth_m[held], initial=0))
    )
    top = min(0.0, float(np.nanmin(cast.series.depth_m)))
    axes[0][0].set_ylim(max(deepest * 1.05, 0.5), top)  # depth increasing downwards
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=4, fontsize=7)
    simulated = " - SIMULATED" if any(r.simulated for r in cast.readings) else ""
    fig.suptitle(
        f"Cast {cast.cast.id}, {iso_utc(cast.cast.start_wall_s)[:19]}Z, "
        f"{cast.cast.lat_deg:.5f}, {cast.cast.lon_deg:.5f}: "
        f"{survey.settings.bin_m:g} m bins{simulated}",
        fontsize=10,
    )
    return fig


def plot_cast(survey: Survey, cast: ProfiledCast, path: Path) -> None:
    cast_figure(survey, cast).savefig(str(path), dpi=DPI)
