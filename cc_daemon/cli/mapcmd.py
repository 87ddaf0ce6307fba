"""`cc-daemon map`: a survey's lake floor from its soundings, every product in one directory.

This module owns the command's surface: its arguments, the `[survey]` settings it
reads (the drafts, the quality control, who made the map), its messages and its
exit status (0 written; 1 no journal, no such survey, nothing to map, a missing
package; 2 wrong arguments). It reads the journal through `JournalReader` only,
so it is safe beside the running daemon; the products are `export.mapproducts`'.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from cc_daemon.cli.data import journal_path
from cc_daemon.cli.surveys import choose_survey, survey_choice
from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.store import JournalReader, StoreError
from cc_daemon.store.surveys import ALL, LATEST

if TYPE_CHECKING:
    from cc_daemon.config.survey import SurveySettings

METHODS = ("linear", "cubic", "thin-plate")  # science.bathymetry.interpolate.METHODS


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive number of metres")
    return value


def _level(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of metres") from None
    if not -500.0 <= value <= 9000.0:
        raise argparse.ArgumentTypeError(f"{text!r}: a water level is -500 to 9000 m")
    return value


def add_command(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "map",
        help="map the lake floor of a survey: grid, GeoTIFF, contours, hypsography, map",
        description="Grid a survey's soundings (the fixes' sonar and this computer's Ping1D)"
        " into the lake floor, and write into DIR: bathymetry.nc (CF-1.8, ACDD 1.3),"
        " depth.tif (GeoTIFF), contours.geojson, hypsography.csv, map.png and summary.txt."
        " Needs the 'science', 'netcdf' and 'plot' extras. See docs/maps.md.",
    )
    parser.add_argument("--db", type=str, default=None, metavar="PATH", help="the journal")
    parser.add_argument(
        "--config",
        metavar="PATH",
        help="the configuration whose [survey] keys to use (default: the daemon's search)",
    )
    parser.add_argument(
        "--survey",
        type=survey_choice,
        default=LATEST,
        metavar="N",
        help="which survey (a daemon run): its number or 'latest' (default: latest)",
    )
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="where to write")
    parser.add_argument(
        "--water-level",
        type=_level,
        metavar="M",
        help="the water level of the survey's day, metres above sea level: adds the bed's"
        " elevation",
    )
    parser.add_argument(
        "--cell", type=_positive, metavar="M", help="cell size (default: line spacing / 4)"
    )
    parser.add_argument(
        "--max-distance",
        type=_positive,
        metavar="M",
        help="cells farther than this from a sounding stay empty (default: 0.75 x spacing)",
    )
    parser.add_argument(
        "--interpolation", choices=METHODS, default="linear", help="(default: linear)"
    )
    parser.add_argument(
        "--interval", type=_positive, metavar="M", help="the hypsography's depth step"
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from cc_daemon.export import OptionalDependencyError

    if args.survey == ALL:
        print("cc-daemon map: one survey at a time: --survey N or latest", file=sys.stderr)
        return 2
    try:
        settings = load_settings(None if args.config is None else Path(args.config)).survey
    except ConfigError as exc:
        print(f"cc-daemon map: {exc}", file=sys.stderr)
        return 2
    args.db = None if args.db is None else Path(args.db)
    try:
        return _map(args, settings, Path(args.output))
    except (StoreError, OptionalDependencyError, ValueError) as exc:
        print(f"cc-daemon map: {exc}", file=sys.stderr)
        return 1
    except ImportError as exc:
        print(
            f"cc-daemon map: {exc.name or exc} is not installed: the map needs the 'science',"
            " 'netcdf' and 'plot' extras (in a clone: make extras)",
            file=sys.stderr,
        )
        return 1
    except OSError as exc:
        print(f"cc-daemon map: {exc.strerror or exc}: {exc.filename or ''}", file=sys.stderr)
        return 1


def _map(args: argparse.Namespace, settings: SurveySettings, output: Path) -> int:
    from cc_daemon.export.bathy_netcdf import missing_metadata
    from cc_daemon.export.bathymap import MapOptions, make_map
    from cc_daemon.export.mapproducts import write_all
    from cc_daemon.export.mapsummary import text

    options = MapOptions(
        survey=settings,
        cell_m=args.cell,
        max_distance_m=args.max_distance,
        method=args.interpolation,
        interval_m=args.interval,
        water_level_m=args.water_level,
    )
    db = journal_path(args)
    with JournalReader(db) as reader:
        choose_survey(reader, args.survey, "map")
        chosen = [s for s in reader.surveys() if s.id == reader.survey]
        if not chosen:
            raise StoreError(f"no survey in {db}: the daemon never recorded a fix there")
        survey_map = make_map(reader, chosen[0], options)
    paths = write_all(survey_map, output)
    sys.stdout.write(text(survey_map))
    print(f"wrote {', '.join(p.name for p in paths.values())} to {output}", file=sys.stderr)
    missing = missing_metadata(survey_map)
    if missing:
        print(
            f"note: the grid's metadata lacks who made it ({', '.join(missing)} are not set"
            " in the configuration): set them for a complete ACDD record",
            file=sys.stderr,
        )
    return 0
