"""Data commands only read: they leave nothing beside the journal (issue 20).

Every command that reads a journal (casts, export, plot, snapshot, sonde
export and plot) opens it read-only the SQLite way and, for a journal nobody
has open, `immutable`: no `-wal` or `-shm` is left beside it, and a journal on
a read-only filesystem (a tmpfs remounted read-only, in a private mount
namespace) is read as well as a writable one.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cc_daemon.store import Journal
from cc_daemon.store.synthetic import FakeClock, write_survey

REPO = Path(__file__).resolve().parent.parent

# Every data command, with the status it gives on the survey below (the
# survey has no sonde: `sonde plot` says so and exits 1).
COMMANDS: dict[str, tuple[list[str], int]] = {
    "casts": (["casts"], 0),
    "export-samples": (["export", "--format", "csv"], 0),
    "export-telemetry": (["export", "--format", "csv", "--what", "telemetry"], 0),
    "export-events": (["export", "--format", "csv", "--what", "events"], 0),
    "export-geojson": (["export", "--format", "geojson", "-o", "{out}/s.geojson"], 0),
    "export-netcdf": (["export", "--format", "netcdf", "-o", "{out}/s.nc"], 0),
    "plot-cast": (["plot", "--cast", "2", "-o", "{out}/c.png"], 0),
    "plot-survey": (["plot", "--survey", "-o", "{out}/s.png"], 0),
    "snapshot": (["snapshot", "{out}/copy.db"], 0),
    "sonde-export": (["sonde", "export", "--format", "csv"], 0),
    "sonde-plot": (["sonde", "plot", "--cast", "2", "-o", "{out}/p.png"], 1),
}

RUN_ALL = textwrap.dedent(
    """
    import contextlib, io, json, os, subprocess, sys
    from pathlib import Path
    from cc_daemon.cli.app import main

    db, out, commands = Path(sys.argv[1]), sys.argv[2], json.loads(sys.argv[3])
    if len(sys.argv) > 4:  # make the journal's directory a read-only filesystem
        card = db.parent
        journal = Path(sys.argv[4])
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64m", "tmpfs", str(card)], check=True)
        (card / db.name).write_bytes(journal.read_bytes())
        subprocess.run(["mount", "-o", "remount,ro", str(card)], check=True)
    results = {}
    for name, argv in commands.items():
        argv = [a.replace("{out}", out) for a in argv]
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            try:
                code = main([*argv, "--db", str(db)] if argv[0] != "snapshot"
                            else [argv[0], "--db", str(db), *argv[1:]])
            except SystemExit as exc:
                code = exc.code
        results[name] = [code, err.getvalue()]
    results["_beside"] = sorted(os.listdir(db.parent))
    print(json.dumps(results))
    """
)


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("survey") / "survey.db"
    clock = FakeClock()
    with Journal(db, monotonic=clock.monotonic, wall=clock.wall) as j:
        write_survey(j, clock, duration_s=900, cast_every_s=300)
    assert sorted(os.listdir(db.parent)) == ["survey.db"]  # the writer's close removed its log
    return db


def _run(db: Path, out: Path, *mount: str, unshare: bool = False) -> dict[str, list[object]]:
    commands = {name: argv for name, (argv, _) in COMMANDS.items()}
    argv = [sys.executable, "-c", RUN_ALL, str(db), str(out), json.dumps(commands), *mount]
    if unshare:
        argv = ["unshare", "-m", "--propagation", "private", *argv]
    env = {**os.environ, "PYTHONPATH": str(REPO), "MPLBACKEND": "Agg"}
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    result: dict[str, list[object]] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def _check(results: dict[str, list[object]]) -> None:
    for name, (_, expected) in COMMANDS.items():
        code, err = results[name]
        assert code == expected, f"{name}: {err}"
        assert "Traceback" not in str(err), f"{name}: {err}"
    assert results["_beside"] == ["survey.db"]  # no -wal, no -shm


def test_data_commands_leave_nothing_beside_the_journal(journal: Path, tmp_path: Path) -> None:
    here = tmp_path / "data"
    here.mkdir()
    db = here / "survey.db"
    shutil.copyfile(journal, db)
    _check(_run(db, tmp_path))
    assert (tmp_path / "copy.db").stat().st_size > 0


def test_data_commands_read_a_journal_on_a_read_only_filesystem(
    journal: Path, tmp_path: Path
) -> None:
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare to remount a filesystem read-only")
    card = tmp_path / "card"
    card.mkdir()
    _check(_run(card / "survey.db", tmp_path, str(journal), unshare=True))
    assert (tmp_path / "copy.db").stat().st_size > 0
