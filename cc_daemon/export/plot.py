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
from cc_daemon.export import estimates
from cc_daemon.export.mapframe import LocalFrame, figure, metric_axes, place_labels, shown
from cc_daemon.store import stations as station_rules
from cc_daemon.store.records import CastRecord, EventRecord, FixRecord, SampleRecord, iso_utc
from cc_daemon.store.stations import Place, Station, names

PHASE_COLOURS = {
    "soaking": "#8dd3c7",
    "descending": "#80b1d3",
    "dwelling": "#b3de69",
    "ascending": "#fdb462",
    "aborting": "#fb8072",
    "stranded": "#bc80bd",
}
DPI = 120
_ESTIMATE = "#c0392b"  # an estimated depth: red, dashed, over a hatched range
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


def plot_cast(
    cast: CastRecord,
    samples: Sequence[SampleRecord],
    path: Path,
    events: Sequence[EventRecord] = (),
) -> None:
    """Write a figure of cast `cast`'s depth against time to `path` (PNG, PDF or SVG).
    `events`: the journal's, for the depths that are estimates and those between samples."""
    fmt = output_format(path)
    cast_figure(cast, samples, events).savefig(path, dpi=DPI, format=fmt)


def cast_figure(
    cast: CastRecord, samples: Sequence[SampleRecord], events: Sequence[EventRecord] = ()
) -> Any:
    """The cast's figure (a matplotlib `Figure`), not yet written anywhere.

    Measured depths are a solid black line; depths the winch could only estimate
    (`export.estimates`) a dashed one over a band of where the probe may be; the
    winch's depth at a fault between two samples a diamond. The title's depth is
    the trace's, and says so when it is an estimate."""
    if not samples:
        raise ValueError(f"cast {cast.id} has no depth samples to plot")
    fig = figure(8.0, 4.5)
    from matplotlib.patches import Patch  # after _figure, which reports a missing matplotlib

    ax = fig.add_subplot()
    estimate = estimates.of_casts([cast], events).get(cast.id)
    points = estimates.trace(cast, samples, events, estimate)
    times = [p.mono_s - cast.start_mono_s for p in points]
    depths = [p.depth_m for p in points]

    seen: dict[str, None] = {}
    for phase, start, end in _phase_spans(times, [p.phase for p in points]):
        ax.axvspan(start, end, color=PHASE_COLOURS.get(phase, "#d9d9d9"), alpha=0.5, lw=0)
        seen.setdefault(phase)
    handles: list[Any] = [
        Patch(color=PHASE_COLOURS.get(p, "#d9d9d9"), alpha=0.5, label=shown(p)) for p in seen
    ]
    known = [i for i, p in enumerate(points) if p.low_m is None]
    guessed = [i for i, p in enumerate(points) if p.low_m is not None]
    (line,) = ax.plot(
        [times[i] for i in known],
        [depths[i] for i in known],
        color="black",
        marker=".",
        lw=1.2,
        label="probe depth, measured by the winch",
    )
    lines: list[Any] = [line]
    if guessed:
        # From the last measured depth: the jump to the first estimate is a guess too.
        joined = ([known[-1]] if known and known[-1] < guessed[0] else []) + guessed
        low = [points[i].low_m or 0.0 for i in guessed]
        high = [points[i].high_m or 0.0 for i in guessed]
        band = ax.fill_between(
            [times[i] for i in guessed],
            low,
            high,
            step="post",
            facecolor="none",
            edgecolor=_ESTIMATE,
            hatch="//",
            lw=0,
            label=f"where the probe may be ({min(low):.2f} to {max(high):.2f} m)",
        )
        (guess,) = ax.plot(
            [times[i] for i in joined],
            [depths[i] for i in joined],
            color=_ESTIMATE,
            ls="--",
            marker=".",
            lw=1.2,
            label=f"best estimate ({estimate.by if estimate and estimate.by else 'the count'}"
            "; not measured)",
        )
        lines += [guess, band]
    between = [i for i, p in enumerate(points) if not p.sampled]
    if between:
        lines.append(
            ax.scatter(
                [times[i] for i in between],
                [depths[i] for i in between],
                marker="D",
                s=30,
                color="black" if not guessed else _ESTIMATE,
                zorder=3,
                label="the winch's depth at the fault (between samples)",
            )
        )
    handles = lines + handles
    deepest = max(depths)
    if cast.planned_depth_m > 0:  # a refused station has no plan to draw
        handles.append(
            ax.axhline(cast.planned_depth_m, color="tab:blue", ls="--", lw=1, label="planned depth")
        )
        deepest = max(deepest, cast.planned_depth_m)
    if guessed:
        deepest = max(deepest, *(points[i].high_m or 0.0 for i in guessed))
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
        f"Cast {cast.id} · {shown(cast.outcome or 'running')} · {_reached(points)}"
        f"\n{_when(cast.start_wall_s)}{clock}",
        fontsize="medium",
    )
    ax.grid(True, alpha=0.3)
    # Beside the axes, never on them: every corner of a cast holds data (the
    # descent, the dwell at the bottom, the way up).
    fig.legend(handles=handles, loc="outside right upper", fontsize="small")
    return fig


def _reached(points: Sequence[estimates.Point]) -> str:
    """How deep the trace goes, as the trace shows it: measured, or an estimate."""
    measured = [p.depth_m for p in points if p.low_m is None]
    guessed = [p for p in points if p.low_m is not None]
    if not guessed:
        return f"reached {_metres(max(measured))}"
    text = f"measured down to {_metres(max(measured))}" if measured else "no depth measured"
    low = min(p.low_m or 0.0 for p in guessed)
    high = max(p.high_m or 0.0 for p in guessed)
    return text + f"\nthen estimated: {low:.2f} to {high:.2f} m"


def plot_survey(
    casts: Sequence[CastRecord],
    fixes: Sequence[FixRecord],
    path: Path,
    stations: Sequence[Station] | None = None,
) -> None:
    """Write a map of the track (coloured by sonar depth) and the stations to `path`."""
    fmt = output_format(path)
    survey_figure(casts, fixes, stations).savefig(path, dpi=DPI, format=fmt)


def survey_figure(
    casts: Sequence[CastRecord],
    fixes: Sequence[FixRecord],
    stations: Sequence[Station] | None = None,
) -> Any:
    """The survey map in a local metric frame (equal aspect), each station labelled
    by its name (`store.stations`: the reader's `stations()`; from the casts alone
    if not given) where the label covers no other text and no station. Each
    survey's track is drawn apart: two surveys are never joined by a line. A
    planned station where no cast was asked is drawn too."""
    if not fixes and not casts:
        raise ValueError("the journal holds no track and no cast to plot")
    stations = list(stations) if stations is not None else _stations_of(casts)
    unasked = [s for s in stations if not s.cast_ids]
    frame = LocalFrame.around(
        [f.lat_deg for f in fixes] + [c.lat_deg for c in casts] + [s.lat_deg for s in unasked],
        [f.lon_deg for f in fixes] + [c.lon_deg for c in casts] + [s.lon_deg for s in unasked],
    )
    track_x, track_y = frame.xy([f.lat_deg for f in fixes], [f.lon_deg for f in fixes])
    station_x, station_y = frame.xy([c.lat_deg for c in casts], [c.lon_deg for c in casts])
    other_x, other_y = frame.xy([s.lat_deg for s in unasked], [s.lon_deg for s in unasked])
    width_m = max(*(track_x + station_x + other_x), 1.0)
    height_m = max(*(track_y + station_y + other_y), 1.0)
    fig = figure(9.0, min(max(7.0 * height_m / width_m, 4.0), 11.0) + 1.5)
    ax = fig.add_subplot()
    surveys = sorted({f.session_id or 0 for f in fixes} | {c.session_id or 0 for c in casts})
    for n, survey in enumerate(surveys):
        these = [i for i, f in enumerate(fixes) if (f.session_id or 0) == survey]
        if these:
            ax.plot([track_x[i] for i in these], [track_y[i] for i in these], color="0.6",
                    lw=0.8, zorder=1, label="track" if n == 0 else None)  # fmt: skip
    if fixes:
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
    if unasked:
        ax.scatter(
            other_x,
            other_y,
            s=70,
            zorder=3,
            marker="s",
            facecolors="none",
            edgecolors="0.35",
            label="station planned, no cast asked",
        )
    metric_axes(ax, frame)
    times = [f.wall_s for f in fixes] + [c.start_wall_s for c in casts]
    times += [c.end_wall_s for c in casts if c.end_wall_s is not None]
    several = len(surveys) > 1
    which = f"{len(surveys)} surveys, " if several else ""
    ax.set_title(
        f"Survey {_when(min(times))} to {_when(max(times))}\n{which}{len(fixes)} fixes,"
        f" {len(casts)} casts at {len(stations)} stations"
        + (" (labels: survey:station)" if several else "")
    )
    ax.grid(True, alpha=0.3)
    # Below the axis label, not on it: constrained layout makes room for it.
    fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    named = names(stations)
    prefix = {c.id: f"{c.session_id}:" if several else "" for c in casts}
    place_labels(
        fig,
        ax,
        list(zip(station_x + other_x, station_y + other_y, strict=True)),
        [prefix[c.id] + _station_label(c, named.get(c.id)) for c in casts]
        + [f"{s.name} no cast" for s in unasked],
        fontsize="x-small",
        markers=True,
    )
    return fig


def _stations_of(casts: Sequence[CastRecord]) -> list[Station]:
    """The stations of `casts` without a plan, each survey's named on its own."""
    found: list[Station] = []
    for survey in sorted({c.session_id or 0 for c in casts}):
        found += station_rules.stations(
            [Place(c.id, c.lat_deg, c.lon_deg, c.outcome) for c in casts
             if (c.session_id or 0) == survey],
            None,
        )  # fmt: skip
    return found


def _sounded(distance_m: float, confidence_pct: int) -> bool:
    """A sonar reading worth drawing: some confidence (at most 100 %), and a distance
    that can be a bottom (not 0, not a sentinel such as 4294967295 mm)."""
    return distrust(round(distance_m * 1000), confidence_pct, min_confidence=1) is None


def _station_label(cast: CastRecord, name: str | None = None) -> str:
    """`S3 2.69 m` for a measured cast; the outcome spelled out for any other.
    Without its station's name, the cast's number (`#3`)."""
    where = name or f"#{cast.id}"
    outcome = cast.outcome or "running"
    if outcome == "completed":
        return f"{where} {_metres(cast.reached_depth_m)}"
    if outcome == "skipped-shallow":
        return f"{where} skipped"
    reached = cast.reached_depth_m
    depth = f" at {_metres(reached)}" if reached else ""
    return f"{where} {outcome}{depth}"


def _when(wall_s: float) -> str:
    return iso_utc(wall_s)[:19] + "Z"


def _metres(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f} m"
