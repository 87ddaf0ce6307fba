"""Plots of the journal: one cast's depth against time, and the survey map.

This module owns the two figures of `cc-daemon plot`: a cast (probe depth
against time since the cast started, depth increasing downward, the phases
shaded, the planned depth and the sonar's bottom drawn as lines, the legend
outside the axes so it hides no data) and a survey (the boat's track coloured
by the sonar's water depth, each station marked by how its cast ended: a
measured one with the depth it reached, a skipped, aborted or unfinished one
unmistakably otherwise). The file format follows the output's extension
(PNG, PDF or SVG); any other is refused before anything is drawn.

matplotlib is the optional `plot` extra: it is imported when a plot is drawn,
never when this module is imported, and a missing one raises
`OptionalDependencyError`. It draws with the object-oriented API on the Agg
backend (no pyplot, no global figure state, no display needed on the Pi). It
never reads the journal itself.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from cc_daemon.core.cast.bottom import distrust
from cc_daemon.export.mapframe import LocalFrame, figure, metric_axes, place_labels, shown
from cc_daemon.store.records import CastRecord, FixRecord, SampleRecord, iso_utc

PHASE_COLOURS = {
    "soaking": "#8dd3c7",
    "descending": "#80b1d3",
    "dwelling": "#b3de69",
    "ascending": "#fdb462",
    "aborting": "#fb8072",
    "stranded": "#bc80bd",
}
DPI = 120
FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg"}

# How a station looks on the survey map, by its cast's outcome: only a measured
# one is a filled red triangle; the others are hollow or crossed, and say why.
_STATIONS: dict[str, tuple[str, dict[str, Any]]] = {
    "completed": ("measured", {"marker": "v", "color": "crimson", "edgecolors": "black"}),
    "skipped-shallow": (
        "skipped: too shallow",
        {"marker": "o", "facecolors": "none", "edgecolors": "0.35", "linewidths": 1.5},
    ),
    "aborted": ("aborted", {"marker": "X", "color": "darkorange", "edgecolors": "black"}),
    "unfinished": (
        "unfinished: no R-F (the probe may have stayed down)",
        {"marker": "X", "color": "darkviolet", "edgecolors": "black"},
    ),
    "running": (
        "running",
        {"marker": "v", "facecolors": "none", "edgecolors": "crimson", "linewidths": 1.5},
    ),
}


def output_format(path: Path) -> str:
    """The image format `path`'s extension asks for; ValueError for any other."""
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        known = ", ".join(FORMATS)
        raise ValueError(f"{path}: the extension says which format to write; one of {known}")
    return fmt


def _phase_spans(times: Sequence[float], phases: Sequence[str]) -> list[tuple[str, float, float]]:
    """Runs of one phase as (phase, start, end); a run ends where the next begins."""
    spans: list[tuple[str, float, float]] = []
    start = 0
    for i in range(1, len(times) + 1):
        if i == len(times) or phases[i] != phases[start]:
            end = times[i] if i < len(times) else times[-1]
            spans.append((phases[start], times[start], end))
            start = i
    return spans


def plot_cast(cast: CastRecord, samples: Sequence[SampleRecord], path: Path) -> None:
    """Write a figure of cast `cast`'s depth against time to `path` (PNG, PDF or SVG)."""
    fmt = output_format(path)
    cast_figure(cast, samples).savefig(path, dpi=DPI, format=fmt)


def cast_figure(cast: CastRecord, samples: Sequence[SampleRecord]) -> Any:
    """The cast's figure (a matplotlib `Figure`), not yet written anywhere."""
    if not samples:
        raise ValueError(f"cast {cast.id} has no depth samples to plot")
    fig = figure(8.0, 4.5)
    from matplotlib.patches import Patch  # after _figure, which reports a missing matplotlib

    ax = fig.add_subplot()
    times = [s.mono_s - cast.start_mono_s for s in samples]
    depths = [s.depth_m for s in samples]
    phases = [s.phase for s in samples]

    seen: dict[str, None] = {}
    for phase, start, end in _phase_spans(times, phases):
        ax.axvspan(start, end, color=PHASE_COLOURS.get(phase, "#d9d9d9"), alpha=0.5, lw=0)
        seen.setdefault(phase)
    handles: list[Any] = [
        Patch(color=PHASE_COLOURS.get(p, "#d9d9d9"), alpha=0.5, label=shown(p)) for p in seen
    ]
    (line,) = ax.plot(times, depths, color="black", marker=".", lw=1.2, label="probe depth")
    handles.insert(0, line)
    handles.append(
        ax.axhline(cast.planned_depth_m, color="tab:blue", ls="--", lw=1, label="planned depth")
    )
    deepest = max([*depths, cast.planned_depth_m])
    if _sounded(cast.water_depth_m, cast.sonar_confidence_pct):
        handles.append(
            ax.axhline(
                cast.water_depth_m,
                color="saddlebrown",
                lw=1.5,
                label=f"bottom (sonar, {cast.sonar_confidence_pct} %)",
            )
        )
        deepest = max(deepest, cast.water_depth_m)
    ax.set_ylim(deepest * 1.08 + 0.1, 0.0)  # depth grows downward, the surface on top
    ax.set_xlim(min(times[0], 0.0), max(times[-1], 1.0))
    ax.set_xlabel("time since the cast started (s)")
    ax.set_ylabel("depth (m)")
    clock = "" if cast.start_clock_synced else " (clock not synchronised)"
    ax.set_title(
        f"Cast {cast.id} · {shown(cast.outcome or 'running')} · reached"
        f" {_metres(cast.reached_depth_m)}"
        f"\n{_when(cast.start_wall_s)}{clock}"
    )
    ax.grid(True, alpha=0.3)
    # Beside the axes, never on them: every corner of a cast holds data (the
    # descent, the dwell at the bottom, the way up).
    fig.legend(handles=handles, loc="outside right upper", fontsize="small")
    return fig


def plot_survey(casts: Sequence[CastRecord], fixes: Sequence[FixRecord], path: Path) -> None:
    """Write a map of the track (coloured by sonar depth) and the stations to `path`."""
    fmt = output_format(path)
    survey_figure(casts, fixes).savefig(path, dpi=DPI, format=fmt)


def survey_figure(casts: Sequence[CastRecord], fixes: Sequence[FixRecord]) -> Any:
    """The survey map in a local metric frame (equal aspect), each station labelled
    where the label covers no other text."""
    if not fixes and not casts:
        raise ValueError("the journal holds no track and no cast to plot")
    frame = LocalFrame.around(
        [f.lat_deg for f in fixes] + [c.lat_deg for c in casts],
        [f.lon_deg for f in fixes] + [c.lon_deg for c in casts],
    )
    track_x, track_y = frame.xy([f.lat_deg for f in fixes], [f.lon_deg for f in fixes])
    station_x, station_y = frame.xy([c.lat_deg for c in casts], [c.lon_deg for c in casts])
    width_m = max(*(track_x + station_x), 1.0)
    height_m = max(*(track_y + station_y), 1.0)
    fig = figure(9.0, min(max(7.0 * height_m / width_m, 4.0), 11.0) + 1.5)
    ax = fig.add_subplot()
    if fixes:
        ax.plot(track_x, track_y, color="0.6", lw=0.8, zorder=1, label="track")
        # A zero-confidence reading is no reading, nor is a sentinel distance:
        # grey track only, no colour.
        sounded = [
            i for i, f in enumerate(fixes) if _sounded(f.sonar_distance_m, f.sonar_confidence_pct)
        ]
        if sounded:
            points = ax.scatter(
                [track_x[i] for i in sounded],
                [track_y[i] for i in sounded],
                c=[fixes[i].sonar_distance_m for i in sounded],
                cmap="viridis_r",
                s=20,
                lw=0,
                zorder=2,
            )
            fig.colorbar(points, ax=ax, label="water depth from the sonar (m)", shrink=0.8)
    for outcome, (label, style) in _STATIONS.items():
        these = [i for i, c in enumerate(casts) if (c.outcome or "running") == outcome]
        if these:
            ax.scatter(
                [station_x[i] for i in these],
                [station_y[i] for i in these],
                s=70,
                zorder=3,
                label=f"station, {label}",
                **style,
            )
    metric_axes(ax, frame)
    times = [f.wall_s for f in fixes] + [c.start_wall_s for c in casts]
    times += [c.end_wall_s for c in casts if c.end_wall_s is not None]
    ax.set_title(
        f"Survey {_when(min(times))} to {_when(max(times))}\n{len(fixes)} fixes, {len(casts)} casts"
    )
    ax.grid(True, alpha=0.3)
    # Below the axis label, not on it: constrained layout makes room for it.
    fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    place_labels(
        fig,
        ax,
        list(zip(station_x, station_y, strict=True)),
        [_station_label(c) for c in casts],
        fontsize="x-small",
    )
    return fig


def _sounded(distance_m: float, confidence_pct: int) -> bool:
    """A sonar reading worth drawing: some confidence (at most 100 %), and a distance
    that can be a bottom (not 0, not a sentinel such as 4294967295 mm)."""
    return distrust(round(distance_m * 1000), confidence_pct, min_confidence=1) is None


def _station_label(cast: CastRecord) -> str:
    """`#3 2.69 m` for a measured cast; the outcome spelled out for any other."""
    outcome = cast.outcome or "running"
    if outcome == "completed":
        return f"#{cast.id} {_metres(cast.reached_depth_m)}"
    if outcome == "skipped-shallow":
        return f"#{cast.id} skipped"
    reached = cast.reached_depth_m
    depth = f" at {_metres(reached)}" if reached else ""
    return f"#{cast.id} {outcome}{depth}"


def _when(wall_s: float) -> str:
    return iso_utc(wall_s)[:19] + "Z"


def _metres(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} m"
