"""A real journal and a real status socket for the field page's tests."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import http.client
import os
import re
import resource
import sqlite3
import subprocess
import sys
import threading
import time
import urllib.parse
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from cc_daemon.config.sonde import DEFAULT_PARAMETERS
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, write_survey
from tests.waitkit import until_sync

# What the daemon's status socket serves in the middle of a cast (status_report.py),
# plus a section no version of the page knows: it must still be shown.
STATUS: dict[str, Any] = {
    "daemon": {"state": "serving", "version": "0.1.0", "pid": 1, "host": "boat",
               "uptime_s": 12.0, "wall_time": 1_700_000_000.0},
    "link": {"up": True, "port": "/dev/serial0", "baudrate": 9600, "port_losses": 0,
             "open_attempts": 0},
    "fix": {"timestamp_s": 72, "lat_e7": -372605790, "lon_e7": 404506308, "alt_mm": 0,
            "sonar_distance_mm": 6000, "sonar_confidence_pct": 90, "age_s": 0.4},
    "cast": {"phase": "descending", "cast_id": 3, "planned_depth_m": 5.0, "depth_m": 1.25},
    "winch": {"backend": "sim", "depth_m": 1.25, "moving": True, "at_home": False,
              "fault": None},
    "journal": {"path": "/var/lib/cc-daemon/cc-daemon.db", "writable": True,
                "pending_rows": 2, "disk_free_bytes": 5_000_000_000},
    "counters": {"frames_in": 10, "frames_out": 9},
    "clock": {"synchronised": True, "max_error_s": 0.01, "source": "adjtimex", "detail": ""},
    "tide_gauge": {"level_m": 0.42},
}  # fmt: skip


def status(**changes: dict[str, Any]) -> dict[str, Any]:
    doc = copy.deepcopy(STATUS)
    for section, values in changes.items():
        doc[section] = {**doc.get(section, {}), **values}
    return doc


def make_journal(db: Path) -> Path:
    """Two surveys: a short one, then 30 minutes with casts every 10 minutes, the last
    measured cast with sonde readings (every default parameter) on its way down."""
    clock = FakeClock()
    for minutes in (5, 30):
        journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
        journal.open()
        write_survey(journal, clock, duration_s=minutes * 60, cast_every_s=600)
        if minutes == 30:
            _sonde_readings(journal, db)  # in the survey's own session, as the daemon does
        journal.close()
        clock.advance(3600)
    return db


def _sonde_readings(journal: Journal, db: Path) -> None:
    until_sync(lambda: not journal.health().pending_rows, "the casts on disk (writer thread)")
    with JournalReader(db) as reader:
        cast = [c for c in reader.casts() if c.outcome == "completed"][-1]
    for i in range(8):
        depth = i * 0.5
        values: dict[str, float | None] = {p.name: None for p in DEFAULT_PARAMETERS}
        values.update(depth=depth, temperature=24.0 - depth)
        journal.record_sonde_sample(
            cast_id=cast.id, phase="descending", mono_s=cast.start_mono_s + i,
            wall_s=cast.start_wall_s + i, duration_s=0.08, status="ok", error=None,
            line_out_m=depth, sonde_depth_m=depth, values=values, missing={}, simulated=True,
        )  # fmt: skip


def lengthen(db: Path, copies: int, *, fixes: bool = True) -> None:
    """Repeat the file's latest survey `copies` times after itself, in the same
    session: its fixes (unless not `fixes`), casts and samples, each copy later by
    the survey's span (SQL, not the journal's API: a ten-day survey in seconds)."""
    with contextlib.closing(sqlite3.connect(db)) as conn, conn:
        session, first, last, low, top = conn.execute(
            "SELECT session_id, min(wall_s), max(wall_s), min(id), max(id) FROM fixes"
            " WHERE session_id = (SELECT max(id) FROM sessions)"
        ).fetchone()
        span = last - first + 1.0
        casts = [
            c for (c,) in conn.execute("SELECT id FROM casts WHERE session_id = ?", (session,))
        ]

        def copy(table: str, where: str, args: tuple[Any, ...], shift: float, **fixed: Any) -> int:
            names = [r[1] for r in conn.execute(f"PRAGMA table_info({table})") if r[1] != "id"]
            picked = [
                f"{n} + {shift}" if n.endswith(("mono_s", "wall_s")) else "?" if n in fixed else n
                for n in names
            ]
            cursor = conn.execute(
                f"INSERT INTO {table} ({', '.join(names)}) SELECT {', '.join(picked)}"
                f" FROM {table} WHERE {where}",
                (*[fixed[n] for n in names if n in fixed], *args),
            )
            return int(cursor.lastrowid or 0)

        for k in range(1, copies + 1):
            if fixes:
                # By rowid: the session's own index would be walked whole each time.
                copy(
                    "fixes", "id BETWEEN ? AND ? AND +session_id = ?", (low, top, session), k * span
                )
            for cast in casts:
                made = copy("casts", "id = ?", (cast,), k * span)
                copy("samples", "cast_id = ?", (cast,), k * span, cast_id=made)


# --- `cc-daemon web` itself, as a subprocess and in process -------------------------

REPO = Path(__file__).resolve().parent.parent


class WebProcess:
    """`cc-daemon web` on a free port of 127.0.0.1, every line of its stderr kept (a
    thread reads them, so its log never blocks on a full pipe). `nofile`: its
    descriptor limit (RLIMIT_NOFILE, soft and hard); `tree`: the checkout it runs
    from (another version's, for a benchmark's comparison)."""

    def __init__(
        self,
        journal: Path,
        socket: Path,
        *extra: str,
        nofile: int | None = None,
        env: dict[str, str] | None = None,
        tree: Path = REPO,
    ):
        def limit() -> None:
            if nofile is not None:
                resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

        environ = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
        environ.update(PYTHONPATH=str(tree), CC_DAEMON_LOG__FORMAT="json")
        environ.update(env or {})
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cc_daemon", "web", "--listen", "127.0.0.1:0",
             "--socket", str(socket), "--db", str(journal), *extra],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            env=environ, cwd=tree, preexec_fn=limit,  # noqa: PLW1509 (the test's thread only)
        )  # fmt: skip
        self.lines: list[bytes] = []
        self._started = threading.Event()
        self.port = 0
        self.log_from = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        if not self._started.wait(30) or not self.port:
            self.close()
            raise RuntimeError(f"cc-daemon web did not start: {self.lines!r}")

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)
            found = re.search(rb"http://127\.0\.0\.1:(\d+)/", line)
            if found and not self.port:
                self.port = int(found.group(1))
                self.log_from = len(self.lines)
                self._started.set()
        self._started.set()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/"

    def log(self) -> list[bytes]:
        """What it logged since it said where it listens."""
        return self.lines[self.log_from :]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(15)
        assert self.proc.stderr is not None
        self.proc.stderr.close()

    def __enter__(self) -> WebProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def get(
    url: str,
    *,
    source: str = "127.0.0.1",
    headers: dict[str, str] | None = None,
    timeout: float = 30.0,
) -> tuple[int, dict[str, str], bytes]:
    """One GET over a fresh connection from `source` (any 127.x.y.z address): the
    status, the headers (lower-case names) and the body."""
    parts = urllib.parse.urlsplit(url)
    conn = http.client.HTTPConnection(
        parts.hostname or "", parts.port, timeout=timeout, source_address=(source, 0)
    )
    try:
        conn.request(
            "GET", parts.path + (f"?{parts.query}" if parts.query else ""), headers=headers or {}
        )
        answer = conn.getresponse()
        return answer.status, {k.lower(): v for k, v in answer.getheaders()}, answer.read()
    finally:
        conn.close()


def deadline_poll(check: Callable[[], bool], what: str, seconds: float = 30.0) -> None:
    """Wait until `check()` is true (polled), failing with `what` after `seconds`."""
    end = time.monotonic() + seconds
    while not check():
        if time.monotonic() > end:
            raise AssertionError(f"not within {seconds:g} s: {what}")
        time.sleep(0.05)


async def client_for(sources: Any, limits: Any = None) -> Any:
    """aiohttp's test client on the page's app (`server.build_app`), started."""
    from aiohttp.test_utils import TestClient, TestServer

    from cc_daemon.cli.web.server import build_app

    app = build_app(sources) if limits is None else build_app(sources, limits)
    client: TestClient[Any, Any] = TestClient(TestServer(app))
    await client.start_server()
    return client


@asynccontextmanager
async def served(sources: Any, **kw: Any) -> AsyncIterator[str]:
    """`server.serve` in this test's loop on a free port of 127.0.0.1: its base URL."""
    from cc_daemon.cli.web.server import serve

    where: asyncio.Future[str] = asyncio.get_running_loop().create_future()

    def ready(address: str, *_: Any) -> None:
        where.set_result(address)

    task = asyncio.create_task(serve(sources, "127.0.0.1:0", ready=ready, **kw))
    try:
        await asyncio.wait([where, task], timeout=30, return_when=asyncio.FIRST_COMPLETED)
        if task.done():
            task.result()  # its error
        yield f"http://{where.result()}/"
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
