"""Plots of the sonde's readings: one cast's profiles as small multiples.

This module owns the figure scientists look at first: for one cast, one panel
per parameter (the depth parameter excepted) with the value on x and depth on
y, depth increasing downwards, the way down and the way up drawn apart
(down: filled blue dots and line; up: open orange dots; dwelling: grey),
units in every axis label, and "SIMULATED" in the title when the readings
came from the simulated sonde. Missing values are gaps, never zeros.

matplotlib is imported when drawing (the `plot` extra), object-oriented API on
Agg, like `plot.py`. It never reads the journal itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cc_daemon.export import OptionalDependencyError
from cc_daemon.export.sonde import Column
from cc_daemon.store.reader import CastRecord, iso_utc
from cc_daemon.store.sonde import SondeSampleRecord

DPI = 120


def _figure(width_in: float, height_in: float) -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise OptionalDependencyError("plotting", "matplotlib", "plot") from exc
    return Figure(figsize=(width_in, height_in), layout="constrained")


_STYLES = {
    "descending": {"color": "#1f77b4", "marker": "o", "mfc": "#1f77b4", "label": "down"},
    "ascending": {"color": "#ff7f0e", "marker": "o", "mfc": "none", "label": "up"},
}
_OTHER = {"color": "#999999", "marker": ".", "mfc": "#999999", "label": "holding"}


def _depth(s: SondeSampleRecord) -> float | None:
    return s.sonde_depth_m if s.sonde_depth_m is not None else s.line_out_m


def plot_profiles(
    cast: CastRecord,
    samples: Sequence[SondeSampleRecord],
    columns: Sequence[Column],
    path: Path,
    *,
    depth_parameter: str = "depth",
) -> None:
    """Write a PNG of cast `cast`'s sonde profiles to `path`."""
    readings = [s for s in samples if s.cast_id == cast.id and _depth(s) is not None]
    panels = [c for c in columns if c.name != depth_parameter]
    if not readings or not panels:
        raise ValueError(f"cast {cast.id} has no sonde readings to plot")
    ncols = min(3, len(panels))
    nrows = math.ceil(len(panels) / ncols)
    fig = _figure(3.2 * ncols, 3.6 * nrows)
    axes = fig.subplots(nrows, ncols, sharey=True, squeeze=False)
    deepest = max(_depth(s) or 0.0 for s in readings)
    for index, column in enumerate(panels):
        ax = axes[index // ncols][index % ncols]
        for phase in ("descending", "ascending", None):
            style = _STYLES.get(phase or "", _OTHER)
            group = [s for s in readings if (s.phase == phase if phase else s.phase not in _STYLES)]
            xs = [s.values.get(column.name) for s in group]
            ys = [_depth(s) for s in group]
            pts = [(x, y) for x, y in zip(xs, ys, strict=True) if x is not None]
            if not pts:
                continue
            ax.plot(
                [x for x, _ in pts],
                [y for _, y in pts],
                color=style["color"],
                marker=style["marker"],
                mfc=style["mfc"],
                ms=4,
                lw=0.8 if phase else 0,
                label=style["label"],
            )
        unit = f" [{column.unit}]" if column.unit else ""
        ax.set_xlabel(f"{column.long_name}{unit}", fontsize=8)
        ax.set_title(column.name, fontsize=9)
        ax.grid(True, alpha=0.3)
        if index % ncols == 0:
            ax.set_ylabel("depth [m]")
    for index in range(len(panels), nrows * ncols):
        axes[index // ncols][index % ncols].set_visible(False)
    axes[0][0].set_ylim(max(deepest * 1.05, 0.5), 0.0)  # depth increasing downwards
    axes[0][0].legend(fontsize=7, loc="lower left")
    simulated = " - SIMULATED" if any(s.simulated for s in readings) else ""
    fig.suptitle(
        f"Cast {cast.id}, {iso_utc(cast.start_wall_s)[:19]}Z, "
        f"{cast.lat_deg:.5f}, {cast.lon_deg:.5f}{simulated}",
        fontsize=10,
    )
    fig.savefig(str(path), dpi=DPI)
