"""A lean daemon (issue 22, docs/performance.md): it imports only what its settings
use, and asleep it does not wake.

A real daemon process, started as the service is (JSON log, the simulated winch,
no sonde, no sonar), answers a P-S, idles while the kernel counts its threads'
sleeps, and is stopped with SIGTERM; a wrapper then writes every module it
imported in its life (`tests/modules_at_exit.py`).
"""

from __future__ import annotations

import asyncio
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

from tests.daemonkit import REPO, DaemonProcess
from tests.waitkit import until

HELPER = Path(__file__).with_name("modules_at_exit.py")

# (what must stay out, the module-name prefixes that would mean it came in)
_NEVER = {
    "the simulator": ("cc_daemon.sim",),
    "the data, plot and export commands": ("cc_daemon.cli.data", "cc_daemon.cli.sonde"),
    "the exports": ("cc_daemon.export",),
    "doctor": ("cc_daemon.cli.doctor",),
    "the other commands": ("cc_daemon.cli.status", "cc_daemon.cli.winch", "cc_daemon.cli.decode"),
    "brping with no sonar": ("brping",),
    "gpiozero with the simulated winch": ("gpiozero", "cc_daemon.drivers.winch.gpio"),
    "rich and pygments with a JSON log": ("rich", "pygments"),
    "ssl (the daemon opens no TLS connection)": ("ssl", "_ssl"),
    "pydantic's plugin search": ("pydantic.plugin._loader", "importlib.metadata"),
    "the journal's read side": (
        "cc_daemon.store.reader",
        "cc_daemon.store.records",
        "cc_daemon.store.guard",
        "cc_daemon.store.files",
        "cc_daemon.store.walcheck",
        "cc_daemon.store.damage",
        "cc_daemon.store.salvaged",
        "cc_daemon.store.scratch",
    ),
    "the sonde's modules with no sonde": ("cc_daemon.drivers.sonde",),
    # The lake floor's science and its libraries are the data tools' extra, never the service's.
    "the science floor and its libraries": (
        "cc_daemon.science",
        "numpy",
        "scipy",
        "pyproj",
        "contourpy",
        "tifffile",
    ),
}


def _matches(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def voluntary_switches(pid: int) -> dict[int, int]:
    """Each thread's sleeps so far (the kernel's count of voluntary context switches)."""
    counts = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        status = (task / "status").read_text()
        counts[int(task.name)] = int(status.split("voluntary_ctxt_switches:")[1].split()[0])
    return counts


IDLE_S = 3.0


def _started_row(db: Path) -> bool:
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
            return conn.execute(
                "SELECT count(*) FROM events WHERE kind = 'daemon_started'"
            ).fetchone() == (1,)
    except sqlite3.OperationalError:  # not created yet
        return False


async def _settled(pid: int, quiet_s: float = 0.3) -> bool:
    """No thread of the process woke for `quiet_s`: done with what it was doing."""
    before = voluntary_switches(pid)
    await asyncio.sleep(quiet_s)
    return voluntary_switches(pid) == before


async def test_the_daemon_imports_nothing_it_does_not_use_and_sleeps_when_idle(tmp_path):
    daemon = DaemonProcess(tmp_path)
    dump = tmp_path / "modules.txt"
    try:
        daemon.start(prefix=[sys.executable, str(HELPER), str(dump), "--"])
        await daemon.connect()
        await daemon.wait_answering()
        assert daemon.proc is not None
        pid = daemon.proc.pid
        # The start's rows written, the R-P's log line out, then asleep. A daemon that
        # ticked is still caught: it settles between ticks, then ticks in the 3 s below.
        await until(lambda: _started_row(daemon.db), what="the start journaled")
        await daemon.logged("frame out")
        for _ in range(30):
            if await _settled(pid):
                break
        before = voluntary_switches(pid)
        await asyncio.sleep(IDLE_S)
        after = voluntary_switches(pid)
        daemon.send_signal(signal.SIGTERM)
        assert await daemon.wait_exit() == 0
    finally:
        await daemon.close()
    # Nothing is due: the main thread sleeps through (the line watch ticked ten times
    # a second, then the housekeeping once; a stray wake-up is allowed); every other
    # thread (the journal's writer): not once.
    main = after[pid] - before[pid]
    others = {tid: n - before.get(tid, 0) for tid, n in after.items() if tid != pid}
    assert main <= 2, (main, others)
    assert sum(others.values()) == 0, (main, others)
    modules = set(dump.read_text().split())
    # The dump is the daemon's: its own modules are in it.
    assert {"cc_daemon.daemon.service", "structlog", "serial"} <= modules
    found = {
        what: sorted(m for m in modules if any(_matches(m, p) for p in prefixes))
        for what, prefixes in _NEVER.items()
    }
    assert {what: mods for what, mods in found.items() if mods} == {}


def test_the_first_pass_reads_the_daemon_and_each_command_gets_its_own_options():
    from cc_daemon.cli.app import parse_command_line

    _, daemon = parse_command_line(["--port", "/dev/ttyX", "--log-format", "json"])
    assert (daemon.command, daemon.port, daemon.log_format) == (None, "/dev/ttyX", "json")
    _, status = parse_command_line(["status", "--json"])
    assert status.command == "status" and status.json and callable(status.handler)
    _, survey = parse_command_line(["--simulate", "--stations", "2", "--winch", "gpio-mock"])
    assert survey.simulate and survey.stations == 2 and survey.winch == "gpio-mock"
    _, export = parse_command_line(["--config", "x.toml", "export", "--format", "csv"])
    assert export.command == "export" and export.format == "csv"


def test_models_built_without_plugins_leave_pydantic_its_own_loader_after():
    # A fresh interpreter: the daemon's configuration built with no plugin search;
    # a model built afterwards (anyone's) asks pydantic's real loader again.
    code = (
        "import sys\n"
        "from cc_daemon.ground.leanimports import pydantic_without_plugins\n"
        "with pydantic_without_plugins():\n"
        "    from cc_daemon.config import Settings\n"
        "    Settings()\n"
        "assert 'importlib.metadata' not in sys.modules, 'searched for plugins'\n"
        "assert 'pydantic.plugin._loader' not in sys.modules, 'the stand-in stayed'\n"
        "import pydantic\n"
        "class Later(pydantic.BaseModel):\n"
        "    x: int = 1\n"
        "import pydantic.plugin._loader as loader\n"
        "assert hasattr(loader, 'entry_points'), 'not the real loader'\n"
        "assert Later(x=2).x == 2 and Settings().winch.backend == 'sim'\n"
    )
    _passes_in_a_fresh_interpreter(code)


def test_the_lean_imports_hide_nothing_afterwards():
    # A fresh interpreter: asyncio and structlog come in without ssl and rich, which
    # anyone (pymodbus, the console renderer) can still import afterwards.
    code = (
        "import sys\n"
        "from cc_daemon.ground.leanimports import import_daemon_libraries_lean\n"
        "import_daemon_libraries_lean()\n"
        "assert {'asyncio', 'structlog'} <= set(sys.modules), 'not imported'\n"
        "assert not {'ssl', 'rich'} & set(sys.modules), 'an extra came in'\n"
        "import ssl, rich.console\n"
        "import asyncio\n"
        "asyncio.run(asyncio.sleep(0))\n"
    )
    _passes_in_a_fresh_interpreter(code)


def _passes_in_a_fresh_interpreter(code: str) -> None:
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert done.returncode == 0, done.stderr
