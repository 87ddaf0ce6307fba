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

import itertools
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cc_daemon.export.mapframe import LocalFrame, figure, metric_axes, place_labels, shown
from cc_daemon.export.sonde import Column
from cc_daemon.store.records import CastRecord, iso_utc
from cc_daemon.store.sonde import SondeSampleRecord

DPI = 120


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
    fig = figure(3.2 * ncols, 3.6 * nrows)
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
        unit = f" [{shown(column.unit)}]" if column.unit else ""
        ax.set_xlabel(f"{shown(column.long_name)}{unit}", fontsize=8)
        ax.set_title(shown(column.name), fontsize=9)
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


def _column(columns: Sequence[Column], name: str) -> Column:
    for c in columns:
        if c.name == name:
            return c
    raise ValueError(f"no parameter {name!r}; the map has {', '.join(c.name for c in columns)}")


def _label(column: Column) -> str:
    name = shown(column.long_name)
    return f"{name} [{shown(column.unit)}]" if column.unit else name


def value_near(
    samples: Sequence[SondeSampleRecord], name: str, depth_m: float, within_m: float
) -> float | None:
    """The cast's reading of `name` nearest `depth_m` (no further than `within_m`)."""
    best: tuple[float, float] | None = None
    for s in samples:
        d, v = _depth(s), s.values.get(name)
        if d is None or v is None or abs(d - depth_m) > within_m:
            continue
        if best is None or abs(d - depth_m) < best[0]:
            best = (abs(d - depth_m), v)
    return None if best is None else best[1]


def plot_map(
    casts: Sequence[CastRecord],
    samples: Sequence[SondeSampleRecord],
    columns: Sequence[Column],
    name: str,
    depth_m: float,
    path: Path,
    *,
    within_m: float = 0.5,
) -> int:
    """A map of the stations coloured by `name` at `depth_m`; returns the stations coloured."""
    fig, count = map_figure(casts, samples, columns, name, depth_m, within_m=within_m)
    fig.savefig(str(path), dpi=DPI)
    return count


def map_figure(
    casts: Sequence[CastRecord],
    samples: Sequence[SondeSampleRecord],
    columns: Sequence[Column],
    name: str,
    depth_m: float,
    *,
    within_m: float = 0.5,
) -> tuple[Any, int]:
    """The map of `plot_map`, in a local metric frame, and the stations coloured."""
    column = _column(columns, name)
    found: list[tuple[CastRecord, float]] = []
    empty: list[tuple[CastRecord, None]] = []
    for cast in casts:
        value = value_near([s for s in samples if s.cast_id == cast.id], name, depth_m, within_m)
        if value is None:
            empty.append((cast, None))
        else:
            found.append((cast, value))
    if not found:
        raise ValueError(f"no {name} reading within {within_m:g} m of {depth_m:g} m")
    stations = [c for c, _ in found] + [c for c, _ in empty]
    frame = LocalFrame.around([c.lat_deg for c in stations], [c.lon_deg for c in stations])
    fig = figure(7.0, 6.0)
    ax = fig.add_subplot()
    xs, ys = frame.xy([c.lat_deg for c, _ in found], [c.lon_deg for c, _ in found])
    scatter = ax.scatter(xs, ys, c=[v for _, v in found], cmap="viridis", s=80, edgecolors="black")
    fig.colorbar(scatter, ax=ax, label=_label(column))
    if empty:
        ex, ey = frame.xy([c.lat_deg for c, _ in empty], [c.lon_deg for c, _ in empty])
        ax.scatter(
            ex,
            ey,
            s=60,
            facecolors="none",
            edgecolors="grey",
            label=f"no reading near {depth_m:g} m",
        )
        ax.legend(fontsize=8)
    metric_axes(ax, frame)
    simulated = " - SIMULATED" if any(s.simulated for s in samples) else ""
    ax.set_title(f"{shown(column.name)} at {depth_m:g} m (within {within_m:g} m){simulated}")
    ax.grid(True, alpha=0.3)
    sx, sy = frame.xy([c.lat_deg for c in stations], [c.lon_deg for c in stations])
    place_labels(fig, ax, list(zip(sx, sy, strict=True)), [str(c.id) for c in stations], fontsize=7)
    return fig, len(found)


def along_track_m(casts: Sequence[CastRecord]) -> list[float]:
    """Each station's distance along the survey from the first, metres (equirectangular)."""
    out = [0.0]
    for a, b in itertools.pairwise(casts):
        lat = math.radians((a.lat_deg + b.lat_deg) / 2)
        dx = math.radians(b.lon_deg - a.lon_deg) * math.cos(lat) * 6_371_000
        dy = math.radians(b.lat_deg - a.lat_deg) * 6_371_000
        out.append(out[-1] + math.hypot(dx, dy))
    return out


def plot_section(
    casts: Sequence[CastRecord],
    samples: Sequence[SondeSampleRecord],
    columns: Sequence[Column],
    name: str,
    path: Path,
) -> int:
    """A depth-distance section of `name` along the stations in survey order (way down)."""
    column = _column(columns, name)
    distance = dict(zip((c.id for c in casts), along_track_m(casts), strict=True))
    # The way down only, as is usual for sections: the way up is the same water read by
    # lagging sensors (all readings if a cast has no way down, e.g. a bottom contact at once).
    down = {s.cast_id for s in samples if s.phase == "descending"}
    samples = [s for s in samples if s.phase == "descending" or s.cast_id not in down]
    points = [
        (distance[s.cast_id], d, v)
        for s in samples
        if s.cast_id in distance
        and (d := _depth(s)) is not None
        and (v := s.values.get(name)) is not None
    ]
    if not points:
        raise ValueError(f"no {name} readings to draw")
    fig = figure(9.0, 4.5)
    ax = fig.add_subplot()
    scatter = ax.scatter(
        [p[0] for p in points], [p[1] for p in points], c=[p[2] for p in points],
        cmap="viridis", s=30, marker="s",
    )  # fmt: skip
    fig.colorbar(scatter, ax=ax, label=_label(column))
    for cast in casts:
        ax.axvline(distance[cast.id], color="grey", lw=0.5, alpha=0.5)
        ax.annotate(str(cast.id), (distance[cast.id], 0.0), fontsize=7, ha="center",
                    xytext=(0, 4), textcoords="offset points")  # fmt: skip
    ax.set_ylim(max(p[1] for p in points) * 1.05 + 0.1, 0.0)  # depth increasing downwards
    ax.set_xlabel("distance along the survey [m] (stations numbered by cast)")
    ax.set_ylabel("depth [m]")
    simulated = " - SIMULATED" if any(s.simulated for s in samples) else ""
    ax.set_title(f"{shown(column.name)} along the survey, way down{simulated}", pad=14)
    fig.savefig(str(path), dpi=DPI)
    return len(points)
