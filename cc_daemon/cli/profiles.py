"""`cc-daemon profiles`: a survey's sonde casts as profiles a limnologist can publish.

This module owns the command: which casts (a survey, or one cast), the options
(`--hypsography`, `--bin-m`, `--lag-correction`, `--no-plots`), the directory of
products and the lines it says on stderr (docs/profiles.md):

    DIR/profiles.nc        binned profiles, CF NetCDF (featureType = profile)
    DIR/profiles.csv       the same, one row per cast, way and bin
    DIR/stations.csv       each cast's derived numbers (thermocline, metalimnion,
    DIR/stations.geojson   Schmidt stability, DCM, oxycline, hypoxia, surface, bottom)
    DIR/cast-N.png         each cast's binned profiles over its raw readings
    DIR/section-P.png      each parameter along the survey against depth

It reads the journal read-only through `JournalReader`, like the other data
commands. Exit status: 0 done; 1 no journal, no profile, a bad hypsography file,
or an optional package missing (what could be written is written); 2 bad usage.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from cc_daemon.cli.data import journal_path
from cc_daemon.cli.surveys import add_survey_option, choose_survey
from cc_daemon.export import OptionalDependencyError
from cc_daemon.store import JournalReader, StoreError

if TYPE_CHECKING:
    from cc_daemon.export.profiles.survey import Survey
    from cc_daemon.science.hypsography import Hypsography
    from cc_daemon.store import CastRecord

EXIT_PROBLEM, EXIT_USAGE = 1, 2
SCHMIDT_MISSING = (
    "Schmidt stability: missing (an empty cell, flagged no_hypsography): it needs the "
    "lake's hypsography, and the survey's own soundings could not make one ({why}); give "
    "--hypsography FILE (a depth_m,area_m2,volume_m3 table, as `cc-daemon map` writes it)"
)


def _bin(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.01 <= value <= 5.0:
        raise argparse.ArgumentTypeError(f"{text!r}: a bin is 0.01 to 5 m thick")
    return value


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "profiles",
        help="binned, lag-corrected profiles, the stations' thermocline, oxygen and "
        "chlorophyll, plots and sections",
        description="Make a survey's sonde casts into profiles: loop edited, lag corrected,"
        " bin averaged; read for stratification with rLakeAnalyzer's definitions. Writes CF"
        " NetCDF and CSV profiles, a stations table (CSV, GeoJSON), a plot per cast and a"
        " section per parameter into DIR. Needs the 'science' extra (numpy); NetCDF and"
        " plots need 'netcdf' and 'plot'.",
    )
    p.add_argument("--db", type=Path, metavar="PATH", help="the journal file (as for export)")
    add_survey_option(p)
    p.add_argument("--cast", type=int, metavar="N", help="only cast N (any survey)")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="DIR",
        required=True,
        help="the directory of products (made if missing)",
    )
    p.add_argument(
        "--hypsography",
        type=Path,
        metavar="FILE",
        help="the lake's depth_m,area_m2,volume_m3 table, for Schmidt stability",
    )
    p.add_argument(
        "--bin-m",
        type=_bin,
        metavar="M",
        help="bin thickness (default: what the casts were planned for, else 0.25)",
    )
    p.add_argument(
        "--lag-correction",
        choices=("inverse", "shift", "none"),
        default=None,
        help="how sensor lags are corrected (default: inverse, or none for casts planned to"
        " resolve no lag; docs/profiles.md)",
    )
    p.add_argument("--no-plots", action="store_true", help="write the tables only")
    p.set_defaults(handler=run)


def _say(line: str) -> None:
    print(line, file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    if args.cast is not None and args.cast < 1:
        _say("cc-daemon profiles: --cast must be a cast id (>= 1)")
        return EXIT_USAGE
    if args.output.exists() and not args.output.is_dir():
        _say(f"cc-daemon profiles: -o {args.output}: exists and is not a directory")
        return EXIT_USAGE
    try:
        return _run(args)
    except (StoreError, OptionalDependencyError, ValueError, OSError) as exc:
        _say(f"cc-daemon profiles: {exc}")
        return EXIT_PROBLEM


def _run(args: argparse.Namespace) -> int:
    try:
        from cc_daemon.export.profiles.hypsography_csv import read_hypsography
        from cc_daemon.export.profiles.survey import profile_survey
    except ImportError as exc:  # numpy: the science extra
        raise OptionalDependencyError("profiles", "numpy", "science") from exc
    lake = read_hypsography(args.hypsography) if args.hypsography is not None else None
    why = ""
    db = journal_path(args)
    with JournalReader(db) as reader:
        choose_survey(reader, None if args.cast is not None else args.survey, "profiles")
        casts = reader.casts(cast_id=args.cast)
        if args.cast is not None and not casts:
            raise StoreError(f"no cast {args.cast} in {db}")
        if lake is None:
            lake, why = _survey_lake(db, reader.survey, casts)
        survey = profile_survey(
            casts,
            reader.sonde_samples(cast_id=args.cast),
            reader.events(),
            bin_m=args.bin_m,
            method=args.lag_correction,
            lake=lake,
        )
    for note in survey.notes:
        _say(f"note: {note}")
    args.output.mkdir(parents=True, exist_ok=True)
    problems = write_tables(survey, args.output)
    if lake is None:
        _say(SCHMIDT_MISSING.format(why=why))
    elif lake.covered_fraction < 1.0:
        _say(f"note: the hypsography covers {lake.covered_fraction:.0%} of the lake")
    if not args.no_plots:
        problems += _plots(survey, args.output)
    return EXIT_PROBLEM if problems else 0


def _survey_lake(
    db: Path, survey: int | None, casts: list[CastRecord]
) -> tuple[Hypsography | None, str]:
    """The hypsography the survey's own soundings make, as `cc-daemon map` would map
    them (its defaults), said in one line; (None, why) when they make none."""
    sessions = {c.session_id for c in casts if c.session_id is not None}
    if survey is None and len(sessions) != 1:
        return None, "the casts span more than one survey"
    try:
        from cc_daemon.export.bathymap import survey_hypsography
    except ImportError:  # scipy, pyproj: the science extra
        return None, "the map's libraries are not installed (the 'science' extra)"
    lake, why = survey_hypsography(db, survey if survey is not None else sessions.pop())
    if lake is not None:
        _say(
            "Schmidt stability: from the hypsography of this survey's own soundings, as"
            " `cc-daemon map` maps them (--hypsography FILE gives another)"
        )
    return lake, why


def write_tables(survey: Survey, out: Path, say: Callable[[str], None] = _say) -> int:
    """The profiles' tables into `out`: profiles.csv, stations.csv and .geojson, and
    profiles.nc; each said in a line. 1 when netCDF4 is missing (the rest written)."""
    from cc_daemon.export.profiles import tables

    bins = len(survey.casts[0].processed.down.depth_m)
    with (out / "profiles.csv").open("w", encoding="utf-8", newline="") as f:
        rows = tables.write_profiles_csv(survey, f)
    say(f"wrote {out / 'profiles.csv'}: {rows} rows (cast, way, bin)")
    with (out / "stations.csv").open("w", encoding="utf-8", newline="") as f:
        count = tables.write_stations_csv(survey, f)
    with (out / "stations.geojson").open("w", encoding="utf-8") as f:
        tables.write_stations_geojson(survey, f)
    say(f"wrote {out / 'stations.csv'} and {out / 'stations.geojson'}: {count} stations")
    try:
        from cc_daemon.export.profiles import netcdf

        written = netcdf.write(survey, out / "profiles.nc")
    except OptionalDependencyError as exc:
        say(f"cc-daemon profiles: profiles.nc not written: {exc}")
        return 1
    say(
        f"wrote {out / 'profiles.nc'}: {written} profiles ({len(survey.casts)} casts, down and "
        f"up) on {bins} bins of {survey.settings.bin_m:g} m"
    )
    return 0


def _plots(survey: Survey, out: Path) -> int:
    from cc_daemon.export.profiles.castplot import plot_cast
    from cc_daemon.export.profiles.sections import plot_section

    try:
        for cast in survey.casts:
            plot_cast(survey, cast, out / f"cast-{cast.cast.id}.png")
        _say(f"wrote {len(survey.casts)} cast plots: {out}/cast-N.png")
        drawn = []
        for column in survey.columns:
            try:
                plot_section(survey, column, out / f"section-{column.name}.png")
                drawn.append(column.name)
            except ValueError as exc:
                _say(f"no section of {column.name}: {exc}")
        if drawn:
            _say(f"wrote {len(drawn)} sections: {out}/section-P.png ({', '.join(drawn)})")
    except OptionalDependencyError as exc:
        _say(f"cc-daemon profiles: plots not drawn: {exc}")
        return 1
    return 0
