"""`cc-daemon sonde export|plot`: the sonde's readings out of the journal.

This module owns the command-line surface for the sonde's data: `sonde export
--format csv|netcdf|geojson` (readings, CF profiles, stations with surface and
bottom values) and `sonde plot --cast N` (the cast's profiles against depth).
It reads the journal read-only through `JournalReader`, like `datacli`, and
takes units and names from the map the daemon journaled (`sonde_started`).
Exit status: 0 done; 1 no journal, no data or no optional package; 2 bad usage.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TextIO

from cc_daemon.cli import exportfiles
from cc_daemon.cli.data import journal_path
from cc_daemon.cli.surveys import add_survey_option, choose_survey, survey_choice
from cc_daemon.export import OptionalDependencyError
from cc_daemon.store import JournalReader, StoreError
from cc_daemon.store.surveys import LATEST


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "sonde",
        help="the sonde's readings: export (CSV, NetCDF-CF, GeoJSON) or plot profiles",
        description="Get the sonde's water-quality readings out of the survey journal.",
    )
    actions = p.add_subparsers(dest="sonde_action", metavar="ACTION", required=True)
    db_help = "the journal file (default: as for `cc-daemon export`)"
    export = actions.add_parser("export", help="readings as CSV, profiles as NetCDF, stations")
    export.add_argument("--db", type=Path, metavar="PATH", help=db_help)
    export.add_argument("--format", required=True, choices=("csv", "netcdf", "geojson"))
    export.add_argument("--cast", type=int, metavar="N", help="only cast N (any survey)")
    add_survey_option(export)
    export.add_argument("-o", "--output", type=Path, metavar="FILE", help="(default: stdout)")
    export.set_defaults(handler=_guarded)
    plot = actions.add_parser(
        "plot",
        help="a cast's profiles, or the survey as a map or a section, as a PNG",
        description="--cast N: the cast's profiles against depth. --survey --parameter P "
        "--depth M: a map of P at M metres; --survey --parameter P --section: P along the "
        "survey against depth.",
    )
    plot.add_argument("--db", type=Path, metavar="PATH", help=db_help)
    which = plot.add_mutually_exclusive_group(required=True)
    which.add_argument("--cast", type=int, metavar="N", help="plot cast N's profiles")
    which.add_argument(
        "--survey",
        type=survey_choice,
        nargs="?",
        const=LATEST,
        metavar="N|all",
        help="plot a survey: the latest, number N, or all of them",
    )
    plot.add_argument("--parameter", metavar="NAME", help="with --survey: what to plot")
    plot.add_argument("--depth", type=float, metavar="M", help="with --survey: a map at M m")
    plot.add_argument("--section", action="store_true", help="with --survey: a section")
    plot.add_argument("-o", "--output", type=Path, metavar="FILE", required=True, help="PNG")
    plot.set_defaults(handler=_guarded)


@contextlib.contextmanager
def _output(path: Path | None) -> Iterator[TextIO]:
    if path is None:
        yield sys.stdout
        sys.stdout.flush()
        return
    with path.open("w", encoding="utf-8", newline="") as out:
        yield out


def _guarded(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except BrokenPipeError:  # `| head`: the reader left; not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (StoreError, OptionalDependencyError, ValueError) as exc:
        print(f"cc-daemon sonde {args.sonde_action}: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"cc-daemon sonde {args.sonde_action}: {exc}", file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    from cc_daemon.export import sonde

    if args.cast is not None and args.cast < 1:
        print("cc-daemon sonde: --cast must be a cast id (>= 1)", file=sys.stderr)
        return 2
    if (
        args.sonde_action == "plot"
        and args.survey is not None
        and (args.parameter is None or (args.depth is None) == (not args.section))
    ):
        print(
            "cc-daemon sonde plot: --survey needs --parameter and one of --depth or --section",
            file=sys.stderr,
        )
        return 2
    if args.sonde_action == "export" and args.format == "netcdf" and args.output is None:
        print("cc-daemon sonde export: --format netcdf needs -o FILE", file=sys.stderr)
        return 2
    db = journal_path(args)
    with JournalReader(db) as reader:
        which = None if args.cast is not None else args.survey
        choose_survey(reader, which, f"sonde {args.sonde_action}")
        casts = reader.casts(cast_id=args.cast)
        if args.cast is not None and not casts:
            raise StoreError(f"no cast {args.cast} in {db}")
        if args.sonde_action == "export" and args.format != "geojson":
            return _export_file(reader, args)
        samples = reader.sonde_samples(cast_id=args.cast)
        columns = sonde.parameter_map(reader.events(), samples)
    if args.sonde_action == "plot":
        from cc_daemon.export import sondeplot

        if args.survey is not None and args.section:
            count = sondeplot.plot_section(casts, samples, columns, args.parameter, args.output)
            noun = f"a section of {args.parameter} ({count} readings)"
        elif args.survey is not None:
            count = sondeplot.plot_map(
                casts, samples, columns, args.parameter, args.depth, args.output
            )
            noun = f"a map of {args.parameter} at {args.depth:g} m ({count} stations)"
        else:
            sondeplot.plot_profiles(casts[0], samples, columns, args.output)
            noun = f"cast {args.cast}'s profiles"
        print(f"plotted {noun} to {args.output}", file=sys.stderr)
        return 0
    with _output(args.output) as out:
        count = sonde.write_geojson(casts, samples, columns, out)
    if args.output is not None:
        print(f"wrote {count} stations to {args.output}", file=sys.stderr)
    return 0


def _export_file(reader: JournalReader, args: argparse.Namespace) -> int:
    """CSV or NetCDF: the files the field page's downloads are (`cli.exportfiles`)."""
    if args.format == "netcdf":
        count, profiles = exportfiles.sonde_netcdf(reader, args.cast, args.output)
        noun = f"{count} readings in {profiles} profiles"
    else:
        with _output(args.output) as out:
            count = exportfiles.sonde_csv(reader, args.cast, out)
        noun = f"{count} readings"
    if args.output is not None:
        print(f"wrote {noun} to {args.output}", file=sys.stderr)
    return 0
