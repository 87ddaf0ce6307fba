"""The commands a person runs after `--simulate`, spelled so they work as printed.

This module owns how a run names the commands that follow it (and those that
watch it while it goes, printed under its header): `cc-daemon`
when the shell's PATH finds this very program, else the path it was started by
(`.venv/bin/cc-daemon` after `make simulate` in a clone), and the `make`
targets when the journal is the clone's own `./simulate.db`. It only builds
strings; it never runs anything.
"""

from __future__ import annotations

import shlex
import shutil
import sys
from pathlib import Path

PROGRAM = "cc-daemon"


def _shown(path: Path, cwd: Path) -> str:
    """`path` as short as it can be typed here: relative beneath `cwd`, else absolute."""
    path = path.absolute()
    try:
        text = str(path.relative_to(cwd))
    except ValueError:
        text = str(path)
    return shlex.quote(text)


def program(argv0: str | None = None, *, cwd: Path | None = None) -> str:
    """How to start cc-daemon again from `cwd`, as this process was started."""
    cwd = cwd or Path.cwd()
    started = Path(argv0 if argv0 is not None else sys.argv[0])
    if started.name != PROGRAM:  # `python -m cc_daemon`, or a test runner
        return f"{_shown(Path(sys.executable), cwd)} -m cc_daemon"
    found = shutil.which(PROGRAM)
    if found is not None and Path(found).resolve() == started.absolute().resolve():
        return PROGRAM
    shown = _shown(started, cwd)
    return shown if "/" in shown else f"./{shown}"


def _has_make_targets(cwd: Path) -> bool:
    try:
        text = (cwd / "Makefile").read_text(encoding="utf-8")
    except OSError:
        return False
    targets = {line.split(":", 1)[0] for line in text.splitlines() if ":" in line}
    return {"export", "plot"} <= targets


def next_steps(
    db: Path, first_cast: int | None, *, argv0: str | None = None, cwd: Path | None = None
) -> list[str]:
    """The follow-up commands for journal `db`, one a line, each runnable as printed."""
    cwd = cwd or Path.cwd()
    run = program(argv0, cwd=cwd)
    where = _shown(db, cwd)
    stem = db.absolute().with_suffix("")
    lines = [
        f"{run} casts --db {where}",
        f"{run} export --db {where} --format csv -o {_shown(stem.with_suffix('.csv'), cwd)}",
        f"{run} sonde export --db {where} --format csv -o {_shown(Path(f'{stem}-sonde.csv'), cwd)}",
        f"{run} plot --db {where} --survey -o {_shown(Path(f'{stem}-survey.png'), cwd)}",
    ]
    if first_cast is not None:
        cast_png = Path(f"{stem}-cast-{first_cast}.png")
        lines.append(f"{run} plot --db {where} --cast {first_cast} -o {_shown(cast_png, cwd)}")
    lines.append(f"{run} web --db {where}   (the field page: open the address it prints)")
    if db.absolute() == cwd / "simulate.db" and _has_make_targets(cwd):
        lines.append("make export plot   (CSV, GeoJSON, NetCDF and the survey map, beside it)")
    return lines


def live_steps(
    db: Path,
    socket: Path,
    findable: bool,
    *,
    argv0: str | None = None,
    cwd: Path | None = None,
) -> list[str]:
    """The commands that watch this run while it goes, each runnable as printed in
    another terminal: `status` and the field page, told the journal (`--db`), or
    the socket itself when the run could not serve where `--db` looks."""
    cwd = cwd or Path.cwd()
    run = program(argv0, cwd=cwd)
    where = _shown(db, cwd)
    ask = f"--db {where}" if findable else f"--socket {_shown(socket, cwd)}"
    web = f"--db {where}" if findable else f"--db {where} --socket {_shown(socket, cwd)}"
    return [f"{run} status {ask} --watch", f"{run} web {web}"]


def map_steps(db: Path, *, argv0: str | None = None, cwd: Path | None = None) -> list[str]:
    """The lake floor's command for journal `db` (its latest survey: this run's), and the
    products it writes, each line runnable or readable as printed."""
    cwd = cwd or Path.cwd()
    out = _shown(Path(f"{db.absolute().with_suffix('')}-map"), cwd)
    return [
        f"{program(argv0, cwd=cwd)} map --db {_shown(db, cwd)} -o {out}",
        f"  writes bathymetry.nc, depth.tif, contours.geojson, hypsography.csv, map.png and"
        f" summary.txt into {out} (docs/maps.md; --pattern lines flies a survey worth mapping)",
    ]


def profile_steps(db: Path, *, argv0: str | None = None, cwd: Path | None = None) -> list[str]:
    """The profiles' command for journal `db` and what it makes (docs/profiles.md)."""
    cwd = cwd or Path.cwd()
    out = _shown(Path(f"{db.absolute().with_suffix('')}-profiles"), cwd)
    return [
        f"{program(argv0, cwd=cwd)} profiles --db {_shown(db, cwd)} -o {out}",
        f"  makes {out}/: profiles.nc and profiles.csv (binned, lag-corrected), stations.csv"
        " and stations.geojson (thermocline, metalimnion, oxycline, DCM, hypoxia, surface,"
        " bottom), cast-N.png (each cast), section-P.png (each parameter along the survey)",
    ]
