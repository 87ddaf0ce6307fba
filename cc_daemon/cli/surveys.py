"""Surveys on the command line: `--survey N|all|latest` and `cc-daemon surveys`.

Every run appends to the same journal; a survey is one daemon session
(`cc_daemon.store.surveys`). The data commands read the latest survey unless
told otherwise, and say so on stderr when the file holds more than one, so a
table or a map never mixes this morning's runs with last week's unasked.
A cast named by its number (`--cast N`) is found in any survey: cast numbers
are unique in a file.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from cc_daemon.store import JournalReader
from cc_daemon.store.records import iso_utc
from cc_daemon.store.surveys import ALL, LATEST, SurveyRecord, parse_survey

SURVEY_HELP = "which survey (a daemon run): its number, 'all' or 'latest' (default: latest)"


def survey_choice(text: str) -> str | int:
    try:
        return parse_survey(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_survey_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--survey", type=survey_choice, default=LATEST, metavar="N|all", help=SURVEY_HELP
    )


def choose_survey(reader: JournalReader, choice: str | int | None, command: str) -> None:
    """Narrow `reader` to the survey asked for (None: every survey, as for `--cast N`),
    and say on stderr which one when the default picked it among several."""
    if choice is None:
        reader.select_survey(ALL)
        return
    chosen = reader.select_survey(choice)
    surveys = reader.surveys()
    if choice == LATEST and chosen is not None and len(surveys) > 1:
        print(
            f"cc-daemon {command}: survey {chosen.id}, the latest of {len(surveys)} in "
            f"{reader.path} ({_span(chosen)}); --survey N or --survey all for others "
            "(cc-daemon surveys lists them)",
            file=sys.stderr,
        )


def _span(s: SurveyRecord) -> str:
    return f"{iso_utc(s.start_wall_s)[:16]}Z to {iso_utc(s.end_wall_s)[:16]}Z"


def format_surveys(surveys: Sequence[SurveyRecord]) -> str:
    lines = [
        f"{'survey':>6}  {'start (UTC)':<17}  {'end (UTC)':<17}  {'stations':>8}"
        f"  {'castable':>8}  {'measured':>8}  {'fixes':>7}  data"
    ]
    for s in surveys:
        if s.simulated is None:
            kind = "not recorded"
        else:
            kind = f"SIMULATED ({s.winch_backend})" if s.simulated else f"real ({s.winch_backend})"
        lines.append(
            f"{s.id:>6}  {iso_utc(s.start_wall_s)[:16] + 'Z':<17}"
            f"  {iso_utc(s.end_wall_s)[:16] + 'Z':<17}  {s.stations:>8}  {s.castable:>8}"
            f"  {s.measured:>8}"
            f"  {s.fixes:>7}  {kind}"
        )
    return "\n".join(lines) + "\n"


def run_surveys(db: Path) -> int:
    with JournalReader(db) as reader:
        surveys = reader.surveys()
    if not surveys:
        print(f"no surveys in {db}", file=sys.stderr)
        return 0
    sys.stdout.write(format_surveys(surveys))
    return 0
