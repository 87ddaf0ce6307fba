"""The data commands of `cc-daemon`: `casts`, `export`, `plot`, `snapshot`, `surveys`.

This module owns the command-line surface for getting data out of the
journal: the arguments, which records each command takes, which writer it
calls, its messages and its exit status (0 done; 1 the journal, the data or an
optional package was not there; 2 the arguments were wrong). `add_commands`
registers the four commands on the main `cc-daemon` parser, each with a
`handler(args) -> int`; `main` runs them alone (`python -m cc_daemon.cli.data`).

It reads the journal only through `JournalReader`, which opens the file
read-only: these commands are safe to run while the daemon is recording, and
never create, migrate or repair a journal (`snapshot` writes only its new copy).
Each says on stderr which journal it read.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TextIO

from cc_daemon.cli.surveys import add_survey_option, choose_survey, run_surveys, survey_choice
from cc_daemon.config import load_settings
from cc_daemon.config.statuspaths import SIMULATOR_JOURNAL
from cc_daemon.core.cast.bottom import MAX_CONFIDENCE_PCT, MAX_SOUNDING_MM
from cc_daemon.core.errors import ConfigError
from cc_daemon.export import OptionalDependencyError
from cc_daemon.store import JournalReader, StoreError, default_store_path
from cc_daemon.store.records import CastRecord, iso_utc, parse_time
from cc_daemon.store.stations import names
from cc_daemon.store.surveys import LATEST

Handler = Callable[[argparse.Namespace], int]


class _UsageError(Exception):
    """The arguments do not make sense together (exit status 2)."""


def _since(text: str) -> float:
    try:
        return parse_time(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not an ISO 8601 time (e.g. 2024-05-01T10:00Z; no offset means UTC)"
        ) from None


def _cast_id(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a cast id (a whole number >= 1)")
    return value


SERVICE_JOURNAL = Path("/var/lib/cc-daemon/cc-daemon.db")  # StateDirectory= of the unit


def journal_path(args: argparse.Namespace) -> Path:
    """The journal to read, said on stderr: `--db`; else where this machine's daemon
    writes it: `store.path` from its configuration (the same file and environment
    lookup), else the systemd service's state directory if a journal is there, else
    the default location if one is there, else the simulator's `./simulate.db`
    if that is the one here."""
    path = _find_journal(args)
    print(f"reading {path}", file=sys.stderr)
    return path


def _find_journal(args: argparse.Namespace) -> Path:
    if args.db is not None:
        return Path(args.db)
    try:
        configured = load_settings().store.path
    except ConfigError as exc:
        print(f"{exc}\n(ignoring the configuration; give --db)", file=sys.stderr)
        configured = None
    if configured is not None:
        return configured
    if "STATE_DIRECTORY" not in os.environ and SERVICE_JOURNAL.exists():
        return SERVICE_JOURNAL
    default = default_store_path()
    if not default.exists() and SIMULATOR_JOURNAL.exists():
        return SIMULATOR_JOURNAL
    return default


def add_commands(
    subparsers: argparse._SubParsersAction[argparse.ArgumentParser],
    *,
    default_db: Path | None = None,
) -> None:
    """Register `casts`, `export`, `plot` and `snapshot`; each sets `handler` to call with the args.

    `--db` defaults to `default_db` if given, else it is resolved when the
    command runs (`journal_path`).
    """
    db = default_db
    db_help = (
        f"the journal file (default: {db})"
        if db is not None
        else "the journal file (default: the configured store.path, else "
        f"{SERVICE_JOURNAL} if it exists, else ./cc-daemon.db, else ./{SIMULATOR_JOURNAL} "
        "if it exists; the file read is said on stderr)"
    )
    since_help = "only data from this UTC time on (ISO 8601, e.g. 2024-05-01T10:00Z)"

    casts = subparsers.add_parser(
        "casts",
        help="list the casts in the survey journal",
        description="A table of the casts: id, start, station, water depth, reached depth,"
        " samples and outcome.",
    )
    casts.add_argument("--db", type=Path, default=db, metavar="PATH", help=db_help)
    casts.add_argument("--since", type=_since, metavar="TIME", help=since_help)
    add_survey_option(casts)
    casts.set_defaults(handler=_run_casts)

    export = subparsers.add_parser(
        "export",
        help="export the survey journal as CSV, GeoJSON or NetCDF",
        description="Export samples, telemetry or events as CSV; the survey (stations, track,"
        " soundings) as GeoJSON; the casts as CF profiles in NetCDF (needs the 'netcdf' extra).",
    )
    export.add_argument("--db", type=Path, default=db, metavar="PATH", help=db_help)
    export.add_argument("--format", required=True, choices=("csv", "geojson", "netcdf"))
    export.add_argument(
        "--what",
        choices=("samples", "telemetry", "events", "sonar"),
        help="with --format csv: which records (default: samples)",
    )
    export.add_argument("--cast", type=_cast_id, metavar="N", help="only cast N (any survey)")
    export.add_argument("--since", type=_since, metavar="TIME", help=since_help)
    add_survey_option(export)
    export.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="FILE",
        help="write to FILE (default: standard output; NetCDF needs a file)",
    )
    export.set_defaults(handler=_run_export)

    plot = subparsers.add_parser(
        "plot",
        help="plot a cast or the survey (PNG, PDF or SVG)",
        description="Plot one cast (depth against time, phases shaded) or the survey (track"
        " coloured by sonar depth, stations). Needs the 'plot' extra (matplotlib).",
    )
    plot.add_argument("--db", type=Path, default=db, metavar="PATH", help=db_help)
    which = plot.add_mutually_exclusive_group(required=True)
    which.add_argument("--cast", type=_cast_id, metavar="N", help="plot cast N (any survey)")
    which.add_argument(
        "--survey",
        type=survey_choice,
        nargs="?",
        const=LATEST,
        metavar="N|all",
        help="plot a survey's map: the latest, number N, or all of them",
    )
    plot.add_argument("--since", type=_since, metavar="TIME", help=f"with --survey: {since_help}")
    plot.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="FILE",
        required=True,
        help="the image: its extension says the format (.png, .pdf or .svg)",
    )
    plot.set_defaults(handler=_run_plot)

    snapshot = subparsers.add_parser(
        "snapshot",
        help="copy the journal consistently, even while the daemon writes it",
        description="Copy the survey journal into one self-contained file with SQLite's online"
        " backup: safe while the service runs, and what to do before pulling the SD card or"
        " copying the data over SSH. Prints what it copied. Never overwrites a file.",
    )
    snapshot.add_argument(
        "dest",
        type=Path,
        metavar="DEST",
        help="the new file (refused if it exists), or a directory to put a dated copy in",
    )
    snapshot.add_argument("--db", type=Path, default=db, metavar="PATH", help=db_help)
    snapshot.set_defaults(handler=_run_snapshot)

    surveys = subparsers.add_parser(
        "surveys",
        help="list the surveys (daemon runs) in the journal",
        description="A table of the surveys: number, start, end, stations, casts measured,"
        " fixes, and whether the data are real or simulated. The data commands read the"
        " latest unless given --survey N or --survey all.",
    )
    surveys.add_argument("--db", type=Path, default=db, metavar="PATH", help=db_help)
    surveys.set_defaults(handler=lambda args: _guarded("surveys", _surveys, args))


def _guarded(name: str, run: Handler, args: argparse.Namespace) -> int:
    """Run a command, turning the errors a user can meet into one line on stderr."""
    try:
        return run(args)
    except _UsageError as exc:
        print(f"cc-daemon {name}: {exc}", file=sys.stderr)
        return 2
    except (StoreError, OptionalDependencyError, ValueError) as exc:
        print(f"cc-daemon {name}: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"cc-daemon {name}: {exc.strerror or exc}: {exc.filename or ''}", file=sys.stderr)
        return 1


def _run_casts(args: argparse.Namespace) -> int:
    return _guarded("casts", _casts, args)


def _run_export(args: argparse.Namespace) -> int:
    return _guarded("export", _export, args)


def _run_plot(args: argparse.Namespace) -> int:
    return _guarded("plot", _plot, args)


def _run_snapshot(args: argparse.Namespace) -> int:
    return _guarded("snapshot", _snapshot, args)


def _snapshot(args: argparse.Namespace) -> int:
    from cc_daemon.store.snapshot import take_snapshot

    db = journal_path(args)
    try:
        report = take_snapshot(db, args.dest)
    except FileExistsError as exc:
        raise _UsageError(f"{exc.filename} exists: refusing to overwrite it") from None
    print(report.describe())
    return 0


def _plural(count: int, noun: str) -> str:
    return f"{count} {noun}" if count == 1 else f"{count} {noun}s"


def _number(value: float | None, width: int, digits: int) -> str:
    return f"{'-':>{width}}" if value is None else f"{value:>{width}.{digits}f}"


def format_casts(casts: Sequence[CastRecord], stations: Mapping[int, str] | None = None) -> str:
    """The `casts` table; a `*` after a time marks a clock that was not synchronised.
    `stations`: each cast's station name (`store.stations`), by cast id."""
    named = stations or {}
    lines = [
        f"{'id':>5}  {'station':<7}  {'start (UTC)':<21} {'lat':>11} {'lon':>12} {'water m':>8}"
        f" {'conf %':>6} {'reached m':>9} {'samples':>7}  outcome"
    ]
    for c in casts:
        start = iso_utc(c.start_wall_s)[:19] + "Z" + (" " if c.start_clock_synced else "*")
        outcome = c.outcome or "running"
        if c.reason:
            outcome += f" ({c.reason})"
        if c.plan.get("blind"):  # no trusted bottom: cast blind (docs/configuration.md)
            outcome += f" [blind: {c.plan['blind']}]"
        # The M frame's distance as it came, unless it cannot be a distance at all.
        impossible = (
            c.water_depth_m * 1000 >= MAX_SOUNDING_MM or c.sonar_confidence_pct > MAX_CONFIDENCE_PCT
        )
        water = None if impossible else c.water_depth_m
        lines.append(
            f"{c.id:>5}  {named.get(c.id, '-'):<7}  {start:<21} {c.lat_deg:>11.7f}"
            f" {c.lon_deg:>12.7f}"
            f" {_number(water, 8, 2)} {c.sonar_confidence_pct:>6}"
            f" {_number(c.reached_depth_m, 9, 2)} {c.samples:>7}  {outcome}"
        )
    if any(not c.start_clock_synced for c in casts):
        lines.append("* the clock was not synchronised: that time may be wrong")
    return "\n".join(lines) + "\n"


def _surveys(args: argparse.Namespace) -> int:
    return run_surveys(journal_path(args))


def _casts(args: argparse.Namespace) -> int:
    db = journal_path(args)
    with JournalReader(db) as reader:
        choose_survey(reader, args.survey, "casts")
        casts = reader.casts(since=args.since)
        stations = names(reader.stations())
    if not casts:
        print(f"no casts in {db}", file=sys.stderr)
        return 0
    sys.stdout.write(format_casts(casts, stations))
    return 0


@contextlib.contextmanager
def _output(path: Path | None, *, newline: str | None = None) -> Iterator[TextIO]:
    if path is None:
        yield sys.stdout
        sys.stdout.flush()
        return
    with path.open("w", encoding="utf-8", newline=newline) as out:
        yield out


def _check_cast(reader: JournalReader, cast_id: int | None, path: Path) -> None:
    if cast_id is not None and not reader.casts(cast_id=cast_id):
        raise StoreError(f"no cast {cast_id} in {path}")


def _export(args: argparse.Namespace) -> int:
    from cc_daemon.export import csv, geojson

    if args.what is not None and args.format != "csv":
        raise _UsageError("--what applies to --format csv only")
    if args.format == "netcdf" and args.output is None:
        raise _UsageError("--format netcdf needs -o FILE (NetCDF is not written to a pipe)")
    what = args.what or "samples"
    if what in ("events", "sonar") and args.cast is not None:
        raise _UsageError(f"--cast does not apply to --what {what}")
    try:
        db = journal_path(args)
        with JournalReader(db) as reader:
            choose_survey(reader, None if args.cast is not None else args.survey, "export")
            _check_cast(reader, args.cast, db)
            if args.format == "netcdf":
                from cc_daemon.export import netcdf

                casts = reader.casts(cast_id=args.cast, since=args.since)
                samples = reader.samples(cast_id=args.cast)
                sonar = netcdf.sonar_during(casts, reader.sonar_readings)
                count = netcdf.write(casts, samples, args.output, sonar=sonar)
                noun = f"{_plural(len(casts), 'cast')}, {_plural(count, 'sample')}"
            elif args.format == "geojson":
                casts = reader.casts(cast_id=args.cast, since=args.since)
                fixes = reader.fixes(cast_id=args.cast, since=args.since)
                with _output(args.output) as out:
                    count = geojson.write(casts, fixes, out)
                noun = _plural(count, "feature")
            else:
                with _output(args.output, newline="") as out:
                    if what == "samples":
                        from cc_daemon.cli.exportfiles import samples_csv

                        count = samples_csv(
                            reader,
                            reader.casts(cast_id=args.cast, since=args.since),
                            reader.samples(cast_id=args.cast, since=args.since),
                            out,
                        )
                    elif what == "telemetry":
                        count = csv.write_fixes(
                            reader.fixes(cast_id=args.cast, since=args.since), out
                        )
                    elif what == "sonar":
                        count = csv.write_sonar(reader.sonar_readings(since=args.since), out)
                    else:
                        count = csv.write_events(reader.events(since=args.since), out)
                noun = f"{_plural(count, 'row')} of {what}"
    except BrokenPipeError:
        # The reader of our stdout left (`| head`): not an error. Point stdout
        # at /dev/null so the interpreter's final flush does not complain.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    if args.output is not None:
        print(f"wrote {noun} to {args.output}", file=sys.stderr)
    return 0


def _plot(args: argparse.Namespace) -> int:
    from cc_daemon.export import plot

    if args.since is not None and args.survey is None:
        raise _UsageError("--since applies to --survey only")
    try:
        plot.output_format(args.output)
    except ValueError as exc:
        raise _UsageError(str(exc)) from None
    db = journal_path(args)
    with JournalReader(db) as reader:
        choose_survey(reader, args.survey, "plot")
        if args.survey is not None:
            casts = reader.casts(since=args.since)
            fixes = reader.fixes(since=args.since)
            plot.plot_survey(casts, fixes, args.output, reader.stations())
            noun = f"the survey ({len(fixes)} fixes, {len(casts)} casts)"
        else:
            _check_cast(reader, args.cast, db)
            cast = reader.casts(cast_id=args.cast)[0]
            samples = reader.samples(cast_id=args.cast)
            plot.plot_cast(cast, samples, args.output, reader.events())
            noun = f"cast {args.cast}"
    print(f"plotted {noun} to {args.output}", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    """A parser with just the data commands (the real one is `cc_daemon.cli.app`)."""
    parser = argparse.ArgumentParser(
        prog="cc-daemon", description="Get the data out of the survey journal."
    )
    add_commands(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handler: Handler = args.handler
    return handler(args)


if __name__ == "__main__":
    raise SystemExit(main())
