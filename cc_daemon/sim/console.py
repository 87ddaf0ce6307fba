"""What a person sees during and after `cc-daemon --simulate`.

This module owns the presentation: a live rich view when stdout is a terminal
(mission progress, the current station, the probe depth as a bar against the
planned depth and the bottom, the last frames each way decoded, recent
events), plain time-stamped lines otherwise (CI logs, pipes), and the
end-of-run summary table.

It only renders what it is given (`ViewState`, `Summary`, events and frames
handed to it); it never talks to the link, the daemon or the clock, and it
decides nothing about the outcome of the run. Output that cannot be written
(a pipe whose reader left, `cc-daemon --simulate | head`; a terminal that
went away) stops the output, never the run: nothing here raises for it.
"""

from __future__ import annotations

import io
import os
import sys
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO, cast

from rich import box
from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from cc_daemon.core.cast.timestamps import swap_bytes
from cc_daemon.core.protocol import CorruptFrame, Message, as_dict
from cc_daemon.sim.autopilot import Violation
from cc_daemon.sim.mission import Mission
from cc_daemon.sim.nextsteps import map_steps, next_steps, profile_steps

EXIT_PROBE_MAY_BE_DOWN = 130  # the daemon's exit status when it had to stop at once
HOME_M = 0.01  # a probe this close to the surface is home

_RECENT_FRAMES = 4
_RECENT_EVENTS = 6
_BAR_WIDTH = 44


def describe_frame(message: Message, order: str = "big") -> str:
    """One short line for a frame: `P-T t=12 40.4506308 N -3.7260579 E sonar 4.620 m 97 %`.

    `order`: how the autopilot's two timestamp bytes are read, as the daemon settled
    it (`core.cast.timestamps`); the codec reads them big-endian, as the manual says,
    and the CC's own frames are big-endian whatever the autopilot does."""
    fields = as_dict(message)
    name = fields.pop("frame")
    stamp = fields.pop("timestamp_s")
    if order == "little" and name.startswith("P-"):
        stamp = swap_bytes(stamp)
    if "lat_e7" in fields:
        sonar_m = fields["sonar_distance_mm"] / 1000
        return (
            f"{name} t={stamp} {fields['lat_e7'] / 1e7:.7f} {fields['lon_e7'] / 1e7:.7f} "
            f"alt {fields['alt_mm'] / 1000:.3f} m  sonar {sonar_m:.3f} m "
            f"{fields['sonar_confidence_pct']} %"
        )
    if "depth_mm" in fields:
        return f"{name} t={stamp} depth {fields['depth_mm'] / 1000:.3f} m"
    return f"{name} t={stamp}"


@dataclass(slots=True)
class ViewState:
    """Everything the live view shows, gathered by the runner each refresh."""

    elapsed_s: float = 0.0
    station_number: int | None = None  # the station the boat is going to or at
    stations_done: int = 0
    station_count: int = 0
    autopilot_phase: str = "starting"
    water_depth_m: float | None = None  # at the current station, when there
    probe_depth_m: float = 0.0
    planned_depth_m: float | None = None
    daemon_phase: str = "starting"
    daemon_link_up: bool = False
    cable_plugged: bool = True
    frames_out: int = 0
    frames_in: int = 0
    corrupt_in: int = 0
    corrupt_at_daemon: int = 0
    problems: int = 0
    excused: int = 0
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    progress: list[tuple[str, str]] = field(default_factory=list)  # (station name, mark)


# How a station looks in the progress line: pending, current, measured, skipped, failed.
MARKS = {"pending": "·", "current": "▸", "measured": "✔", "skipped": "↷", "failed": "✘"}
_MARK_STYLES = {"▸": "bold yellow", "✔": "green", "↷": "cyan", "✘": "bold red", "·": "dim"}


def depth_bar(
    depth_m: float, planned_m: float | None, bottom_m: float | None, width: int = _BAR_WIDTH
) -> Text:
    """The probe as a bar from the surface down to the bottom; `┃` marks the plan."""
    scale = max(bottom_m or 0.0, planned_m or 0.0, depth_m, 1.0)
    filled = min(width, round(depth_m / scale * width))
    mark = None if planned_m is None else min(width - 1, round(planned_m / scale * width))
    bar = Text()
    for i in range(width):
        if i == mark:
            bar.append("┃", style="bold yellow")
        elif i < filled:
            bar.append("█", style="cyan")
        else:
            bar.append("·", style="blue")
    bar.append("▓" if bottom_m is not None else " ", style="rgb(150,110,60)")
    return bar


@dataclass(frozen=True, slots=True)
class StationRow:
    number: int
    lat_deg: float
    lon_deg: float
    water_depth_m: float
    planned_depth_m: float | None
    reached_depth_m: float | None
    duration_s: float | None
    reports: int
    verdict: str
    ok: bool


@dataclass(slots=True)
class Summary:
    """The end-of-run report."""

    seed: int
    elapsed_s: float
    stations: list[StationRow]
    frames_to_daemon: int
    frames_from_daemon: int
    corrupt_from_daemon: int  # frames from the daemon our parser rejected
    corrupt_at_daemon: int | None  # frames from us the daemon's parser rejected
    bits_flipped_out: int
    bits_flipped_in: int
    m_sent: int
    link_drops: int
    daemon_port_losses: int | None
    casts_completed: int | None
    casts_aborted: int | None
    casts_skipped: int | None
    violations: list[Violation]
    db_path: Path | None
    log_path: Path | None
    exit_code: int
    interrupted: bool = False
    notes: list[str] = field(default_factory=list)
    daemon_exit: int | None = None  # None: it did not run here (or did not finish)
    probe_depth_m: float | None = None  # where the probe ended up, when known
    # When that depth is the winch's estimate (its count not trusted): the range it is in.
    probe_range_m: tuple[float, float] | None = None
    remote: bool = False  # the daemon is elsewhere: we know only what it said on the link
    casts_unfinished: int | None = None  # from the journal: left with no R-F (stranded, cut)
    protocol_kept: bool = True  # no unexcused violation, and the daemon did not fail
    measured: int = 0  # castable stations with a complete cast
    castable: int = 0  # stations deep enough to cast (the shoal is not one)
    survey_complete: bool = True  # every station visited and measured (or rightly skipped)
    probe_went_down: bool = True  # some cast lowered the probe
    first_cast_id: int | None = None  # a cast of this run worth plotting
    stranded_at: int | None = None  # the station held with R-L and no R-F (its number)

    @property
    def problems(self) -> list[Violation]:
        return [v for v in self.violations if not v.excused]


def _metres(value: float | None) -> str:
    return "—" if value is None else f"{value:.2f} m"


def summary_table(summary: Summary, *, narrow: bool = False) -> Table:
    """The per-station table; `narrow` puts latitude and longitude on two lines."""
    table = Table(
        title="Survey summary", box=box.SIMPLE_HEAVY, title_justify="left", pad_edge=False
    )
    table.add_column("station", no_wrap=True)
    table.add_column("position", no_wrap=True)
    for number in ("water", "planned", "reached", "cast", "R-M"):
        table.add_column(number, justify="right", no_wrap=True)
    table.add_column("verdict", min_width=12)
    sep = "\n" if narrow else " "
    for row in summary.stations:
        table.add_row(
            f"S{row.number}",
            # Five decimals is about a metre: as good as the boat's GPS.
            f"{row.lat_deg:.5f} N{sep}{abs(row.lon_deg):.5f} {'W' if row.lon_deg < 0 else 'E'}",
            _metres(row.water_depth_m),
            _metres(row.planned_depth_m),
            _metres(row.reached_depth_m),
            "—" if row.duration_s is None else f"{row.duration_s:.1f} s",
            str(row.reports),
            Text(row.verdict, style="green" if row.ok else "bold red"),
        )
    return table


def summary_lines(summary: Summary) -> list[str]:
    """The totals and advice under the table, as plain lines."""
    lines = [
        f"frames: {summary.frames_to_daemon} to the daemon ({summary.m_sent} M), "
        f"{summary.frames_from_daemon} from it; run took {summary.elapsed_s:.1f} s",
    ]
    corrupt = f"corrupt frames: {summary.corrupt_from_daemon} from the daemon"
    if summary.corrupt_at_daemon is not None:
        corrupt += f", {summary.corrupt_at_daemon} rejected by the daemon"
    if summary.bits_flipped_out or summary.bits_flipped_in:
        corrupt += (
            f" (injected: {summary.bits_flipped_out} bits flipped towards the daemon, "
            f"{summary.bits_flipped_in} towards the autopilot)"
        )
    lines.append(corrupt)
    if summary.link_drops or summary.daemon_port_losses:
        lines.append(
            f"link: cable pulled {summary.link_drops} time(s); the daemon lost its port "
            f"{summary.daemon_port_losses or 0} time(s) and reopened it"
        )
    if summary.casts_completed is not None:
        counts = (
            f"daemon: {summary.casts_completed} cast(s) completed, {summary.casts_aborted} "
            f"aborted, {summary.casts_skipped} skipped"
        )
        if summary.casts_unfinished is not None:
            counts += f", {summary.casts_unfinished} unfinished"
        depth = summary.probe_depth_m
        if depth is not None and depth > HOME_M:
            counts += f"; the probe left{_where(summary)} down"
        lines.append(counts)
    problems = summary.problems
    excused = len(summary.violations) - len(problems)
    lines.append(
        f"protocol violations: {len(problems)}"
        + (f" (+{excused} explained by injected faults)" if excused else "")
    )
    lines.extend("  " + v.describe() for v in problems)
    lines.extend(_excused_lines(summary.violations))
    lines.extend(summary.notes)
    if summary.db_path is not None:
        lines.append(f"data stored in {summary.db_path}; next, as typed here:")
        lines.extend("  " + step for step in next_steps(summary.db_path, summary.first_cast_id))
        lines.append("profiles a limnologist can publish:")
        lines.extend("  " + step for step in profile_steps(summary.db_path))
        lines.append("the lake floor from this run's soundings:")
        lines.extend("  " + step for step in map_steps(summary.db_path))
    if summary.log_path is not None:
        lines.append(f"daemon log (JSON lines): {summary.log_path}")
    ending = _ending(summary)
    if ending is not None:
        lines.append(ending)
    lines.append(verdict_line(summary))
    return lines


def verdict_line(summary: Summary) -> str:
    """The last line: did the survey measure its stations, and did the daemon keep the protocol."""
    castable = summary.castable
    noun = "station" if castable == 1 else "stations"
    measured = f"{summary.measured} of {castable} castable {noun} measured"
    survey = "SURVEY OK" if summary.survey_complete else "SURVEY INCOMPLETE"
    if summary.stranded_at is not None:
        survey = (
            f"SURVEY HALTED: probe stranded at S{summary.stranded_at}, "
            "fault reported to the autopilot"
        )
    n = len(summary.problems)
    if summary.protocol_kept:
        protocol = "the daemon kept the protocol"
    elif n:
        protocol = f"PROTOCOL VIOLATED ({n} violation{'' if n == 1 else 's'})"
    else:
        protocol = f"THE DAEMON FAILED (its exit status {summary.daemon_exit})"
    if summary.remote and summary.protocol_kept:
        protocol += " on the wire"
    return f"{survey}: {measured}; {protocol} (exit status {summary.exit_code})"


def _where(summary: Summary) -> str:
    """the probe's last depth, an estimate said as one."""
    depth = summary.probe_depth_m or 0.0
    if summary.probe_range_m is None:
        return f" {depth:.2f} m"
    low, high = summary.probe_range_m
    return f" about {depth:.2f} m (an estimate: between {low:.2f} and {high:.2f} m)"


def _ending(summary: Summary) -> str | None:
    """How the run ended for the probe, saying only what is known."""
    depth = summary.probe_depth_m
    at = "" if depth is None else f" at{_where(summary)}"
    if summary.stranded_at is not None:
        return (
            f"the probe stranded{at}: the daemon sent R-L (the fault, for the ground "
            "station) and no R-F; recover it by hand"
        )
    if summary.daemon_exit == EXIT_PROBE_MAY_BE_DOWN:
        return f"stopped at once: the probe may be down{at}"
    if not summary.interrupted:
        return None
    if summary.remote:
        said = "" if depth is None else f"; it last reported the probe{at}"
        return (
            "interrupted: the simulated autopilot stopped; the daemon on the other end "
            f"carries on as it sees fit{said}"
        )
    if depth is None:
        return "interrupted"
    if depth <= HOME_M and not summary.probe_went_down:
        return "interrupted before any cast: the probe never left home"
    if depth <= HOME_M:
        return "interrupted: the daemon brought the probe home before stopping"
    return f"interrupted: the daemon stopped with the probe{at}"


def _excused_lines(violations: list[Violation]) -> list[str]:
    """Excused violations, one line per kind and reason: they are expected, not news."""
    counts: dict[tuple[str, str], int] = {}
    for v in violations:
        if v.excused_by is not None:
            key = (str(v.kind), v.excused_by)
            counts[key] = counts.get(key, 0) + 1
    return [f"  excused: {n} x {kind} ({reason})" for (kind, reason), n in counts.items()]


class SimConsole:
    """Live view on a terminal, plain lines elsewhere; then the summary."""

    def __init__(self, out: TextIO | None = None, *, live: bool | None = None) -> None:
        self.out = out if out is not None else sys.stdout
        is_tty = _isatty(self.out)
        self.live = is_tty if live is None else live
        self._guard = _GuardedStream(self.out)
        self.rich = Console(
            file=cast(TextIO, self._guard),
            force_terminal=self.live or None,
            width=None if is_tty else 110,
            highlight=False,
        )
        self.state = ViewState()
        self.mission: Mission | None = None
        self.sent: deque[str] = deque(maxlen=_RECENT_FRAMES)
        self.received: deque[str] = deque(maxlen=_RECENT_FRAMES)
        self.events: deque[str] = deque(maxlen=_RECENT_EVENTS)
        self._live: Live | None = None

    @property
    def output_lost(self) -> Exception | None:
        """Why output stopped (the reader left, the terminal went away), if it did."""
        return self._guard.broken

    # ------------------------------------------------------------ lifecycle

    def start(self, mission: Mission, headline: str) -> None:
        """Show `headline` (every line of it), then the live view or the station list."""
        self.mission = mission
        self.state.station_count = len(mission.stations)
        if self.live:
            for line in headline.splitlines():
                self._line(line)
            self._live = Live(
                get_renderable=self.render,
                console=self.rich,
                refresh_per_second=8,
                transient=False,
            )
            self._live.start()
        else:
            for line in headline.splitlines():
                self._line(line)
            for station in mission.stations:
                lat, lon = station.point.lat_lon
                self._line(
                    f"  {station.name} at {lat:.6f}, {lon:.6f}: water {station.water_depth_m:.2f} m"
                    + (" (a shoal: too shallow to cast)" if station.too_shallow else "")
                )

    def stop(self) -> None:
        if self._live is not None:
            self._live.refresh()
            self._live.stop()
            self._live = None

    # ------------------------------------------------------------ feed

    def update(self, state: ViewState) -> None:
        self.state = state

    def event(self, elapsed_s: float, text: str) -> None:
        line = f"{elapsed_s:7.1f} s  {text}"
        self.events.append(line)
        if not self.live:
            self._line(line)

    def frame_out(self, elapsed_s: float, message: Message, order: str = "big") -> None:
        self.sent.append(f"{elapsed_s:7.1f} s  → {describe_frame(message, order)}")

    def frame_in(self, elapsed_s: float, message: Message) -> None:
        text = describe_frame(message)
        self.received.append(f"{elapsed_s:7.1f} s  ← {text}")
        # Plain lines show the cast's progress; R-O and R-P are narrated or routine.
        if not self.live and message.frame in ("R-M", "R-F", "R-L"):
            self._line(f"{elapsed_s:7.1f} s  ← {text}")

    def corrupt_in(self, elapsed_s: float, error: CorruptFrame) -> None:
        self.event(elapsed_s, f"corrupt frame from the daemon: {error.kind} {error.hex()}")

    # ------------------------------------------------------------ output

    def render(self) -> RenderableType:
        s = self.state
        head = Text()
        head.append("cc-daemon --simulate  ", style="bold")
        head.append(f"{s.elapsed_s:6.1f} s   ")
        head.append(f"stations done {s.stations_done}/{s.station_count}   ")
        link = (
            Text("cable pulled", style="bold red")
            if not s.cable_plugged
            else Text("link up", style="green")
            if s.daemon_link_up
            else Text("daemon reopening the port", style="yellow")
        )
        head.append_text(link)

        where = Text("mission ")
        for name, mark in s.progress:
            where.append(f"{name} ")
            where.append(f"{mark}  ", style=_MARK_STYLES.get(mark, ""))
        where.append("  ")
        if s.station_number is not None:
            where.append(f"S{s.station_number} ", style="bold")
        where.append(f"{s.autopilot_phase}  ")
        where.append(f"boat {s.lat_deg:.6f}, {s.lon_deg:.6f}   daemon: {s.daemon_phase}")

        probe = Text("probe ")
        probe.append_text(depth_bar(s.probe_depth_m, s.planned_depth_m, s.water_depth_m))
        probe.append(f" {s.probe_depth_m:5.2f} m")
        legend = Text(
            f"      planned {_metres(s.planned_depth_m)} ┃   bottom {_metres(s.water_depth_m)} ▓",
            style="dim",
        )
        counts = Text(
            f"frames → {s.frames_out}  ← {s.frames_in}   corrupt: {s.corrupt_in} in, "
            f"{s.corrupt_at_daemon} at the daemon   violations: {s.problems}"
            + (f" (+{s.excused} excused)" if s.excused else "")
        )
        frames = Table.grid(padding=(0, 1))
        frames.add_column()
        for line in self.sent:
            frames.add_row(Text(line, style="magenta", no_wrap=True, overflow="ellipsis"))
        for line in self.received:
            frames.add_row(Text(line, style="cyan", no_wrap=True, overflow="ellipsis"))
        events = Group(
            *(Text(line, style="dim", no_wrap=True, overflow="ellipsis") for line in self.events)
        )
        return Panel(
            Group(
                head,
                where,
                probe,
                legend,
                counts,
                Panel(
                    frames,
                    title="last frames: → to the daemon, ← from it",
                    box=box.MINIMAL,
                ),
                events,
            ),
            title="survey",
            box=box.ROUNDED,
        )

    def print_summary(self, summary: Summary) -> None:
        self.stop()
        self.rich.print(summary_table(summary, narrow=self.rich.width < 100))
        for line in summary_lines(summary):
            self._line(line)

    def _line(self, text: str) -> None:
        self.rich.print(Text(text), soft_wrap=True)


def _isatty(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError, OSError):
        return False


class _GuardedStream:
    """The console's output stream: the first write or flush that fails stops all output.

    rich's own answer to a broken pipe is `SystemExit(1)`, raised wherever the
    write was: in the middle of a cast, that would abandon the probe. Here a
    failed write is remembered and everything after it is dropped. The failed
    descriptor is pointed at /dev/null, so the interpreter's last flush of
    stdout at exit does not fail again.
    """

    def __init__(self, out: TextIO) -> None:
        self._out = out
        self.broken: Exception | None = None

    @property
    def encoding(self) -> str:
        return str(getattr(self._out, "encoding", None) or "utf-8")

    def write(self, text: str) -> int:
        if self.broken is None:
            try:
                self._out.write(text)
            except (OSError, ValueError) as exc:  # ValueError: the stream was closed
                self._lose(exc)
        return len(text)

    def flush(self) -> None:
        if self.broken is None:
            try:
                self._out.flush()
            except (OSError, ValueError) as exc:  # ValueError: the stream was closed
                self._lose(exc)

    def isatty(self) -> bool:
        return self.broken is None and _isatty(self._out)

    def fileno(self) -> int:
        return self._out.fileno()

    def _lose(self, exc: Exception) -> None:
        self.broken = exc
        try:
            fd = self._out.fileno()
        except (AttributeError, ValueError, OSError):
            return  # not a descriptor (a StringIO): nothing will flush it again
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(devnull, fd)
            finally:
                os.close(devnull)
        except OSError:
            pass


def render_to_text(render: Callable[[Console], None], width: int = 110) -> str:
    """Render with `render(console)` into plain text (for tests and the docs)."""
    buffer = io.StringIO()
    console = Console(file=buffer, width=width, force_terminal=False, color_system=None)
    render(console)
    return buffer.getvalue()
