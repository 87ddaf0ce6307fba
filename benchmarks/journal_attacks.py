"""A stranger's journal against the read side: time, memory and temporary files (issue 27).

    python -m benchmarks.journal_attacks      (or `make bench`, which runs every benchmark)

Each attack is a real file made hostile (a one-day synthetic survey, 7 MB, as the
base), read by the real command line in a child process with its own temporary
directory, under a deadline (`BENCH_ATTACK_DEADLINE_S`, 20 s: a child still
running then is killed and reported as hanging) and an address-space cap (2 GiB,
so a runaway reader cannot take the machine). For each: the time to its answer,
the answer (exit status and its one line), the child's peak resident memory
(`ru_maxrss`, from `wait4`) and the bytes it left in its temporary directory.
PASS when the answer is one line (exit 1) before the deadline, costing at most 5 s
of CPU (the wall time is printed too, but on a shared machine it follows the
load), in at most 150 MB, leaving nothing behind.

- the `-wal` a symlink to `/dev/zero`, a FIFO, a sparse 3 GiB file;
- `fixes` replaced by an endless recursive view, `samples` by a 12-way self-join
  (read by `export` and by `recover`);
- a 200 MB event detail (`export --what events`), a 50 MB text in a sample
  (`plot --cast 2`), a 50 MB sonde reading (`sonde export`);
- a damaged journal (a garbled page) read as the field page reads it, twenty
  times (the page's four questions, five times): the first request (which
  salvages), the median of the others, the temporary bytes while the process runs
  and after it ends. PASS: the later requests' median within 1 s (the page's
  goal), at most two salvaged copies' bytes while it runs (the cache's bound),
  nothing left.

To measure another tree (e.g. before these fixes), run this module with
`PYTHONPATH` set to that tree: the children import whatever `cc_daemon` it finds.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import resource
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from cc_daemon.store import Journal
from cc_daemon.store.synthetic import FakeClock, write_survey

DEADLINE_S = float(os.environ.get("BENCH_ATTACK_DEADLINE_S", "20"))
CAP_BYTES = 2 << 30
CPU_S = 5.0
RSS_MB = 150.0
PAGE_S = 1.0
REPO = Path(__file__).resolve().parent.parent


@dataclass
class Run:
    seconds: float
    code: int | None  # None: killed at the deadline
    said: str
    peak_mb: float
    left_bytes: int
    cpu_s: float = 0.0  # user and system: what the answer cost, whatever the machine's load
    stdout: str = ""


def _cap() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (CAP_BYTES, CAP_BYTES))


def _bytes_under(path: Path) -> int:
    return sum(p.lstat().st_size for p in path.rglob("*") if not p.is_symlink())


def run_child(argv: list[str], work: Path, deadline_s: float = DEADLINE_S) -> Run:
    """`argv` in a child with its own TMPDIR; its time, answer, peak RSS, temp bytes left."""
    scratch = work / f"tmp-{time.monotonic_ns()}"
    scratch.mkdir()
    out, err = scratch.with_suffix(".out"), scratch.with_suffix(".err")
    env = {**os.environ, "TMPDIR": str(scratch)}
    start = time.monotonic()
    with out.open("wb") as stdout, err.open("wb") as stderr:
        # One thread here: preexec_fn is safe (it only sets the child's cap).
        child = subprocess.Popen(
            argv,
            stdout=stdout,
            stderr=stderr,
            env=env,
            cwd=REPO,
            preexec_fn=_cap,  # noqa: PLW1509
        )
        code: int | None = None
        usage = None
        while time.monotonic() - start < deadline_s:
            pid, status, usage = os.wait4(child.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
                child.returncode = code
                break
            time.sleep(0.01)
        seconds = time.monotonic() - start
        if code is None:
            child.kill()
            _, _, usage = os.wait4(child.pid, 0)
            child.returncode = -9
    lines = [line for line in err.read_text(errors="replace").splitlines() if line.strip()]
    said = next(
        (line for line in lines if line.startswith("cc-daemon ")), lines[-1] if lines else ""
    )
    text = out.read_text(errors="replace")
    return Run(
        seconds,
        code,
        said,
        usage.ru_maxrss / 1024 if usage else 0.0,
        _bytes_under(scratch),
        usage.ru_utime + usage.ru_stime if usage else 0.0,
        text,
    )


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "cc_daemon", *args]


def base_journal(path: Path) -> None:
    clock = FakeClock()
    journal = Journal(path, monotonic=clock.monotonic, wall=clock.wall, max_buffered_rows=10**6)
    journal.open()
    try:
        write_survey(journal, clock, duration_s=86_400, cast_every_s=900)
        deadline = time.monotonic() + 120
        while journal.health().pending_rows and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        journal.close()


def _sql(db: Path, *statements: str) -> None:
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as conn:
        for statement in statements:
            conn.execute(statement)


def _view(db: Path, table: str, body: Callable[[list[str]], str]) -> None:
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as conn:
        names = [str(row[1]) for row in conn.execute(f"PRAGMA table_info({table})")]
        conn.execute(f"ALTER TABLE {table} RENAME TO {table}_real")
        conn.execute(f"CREATE VIEW {table} AS {body(names)}")


def endless(names: list[str]) -> str:
    picked = ", ".join(f"n AS {name}" for name in names)
    return f"WITH RECURSIVE r(n) AS (SELECT 1 UNION ALL SELECT n + 1 FROM r) SELECT {picked} FROM r"


def self_join(table: str) -> Callable[[list[str]], str]:
    def body(names: list[str]) -> str:
        picked = ", ".join(f"t0.{name} AS {name}" for name in names)
        return f"SELECT {picked} FROM " + ", ".join(f"{table}_real t{i}" for i in range(12))

    return body


def _huge(db: Path, table: str, column: str, size: int, where: str) -> None:
    _sql(
        db,
        f"UPDATE {table} SET {column} = substr(hex(zeroblob({(size + 1) // 2})), 1, {size})"
        f" WHERE {where}",
    )


def _sparse(path: Path, size: int) -> None:
    with path.open("wb") as f:
        f.truncate(size)


def _garble(db: Path, page: int) -> None:
    data = bytearray(db.read_bytes())
    size = int.from_bytes(data[16:18], "big") or 65536
    data[(page - 1) * size : page * size] = random.Random(1).randbytes(size)
    db.write_bytes(bytes(data))


def _sonde_rows(db: Path) -> Path:
    values = json.dumps({"depth": 1.0, "temperature": 20.0})
    _sql(
        db,
        "INSERT INTO sonde_samples (session_id, cast_id, phase, mono_s, wall_s, clock_synced,"
        " duration_s, status, error, line_out_m, sonde_depth_m, simulated, values_json,"
        f" missing_json) SELECT 1, 2, 'descending', 1000 + value, 1717229100 + value, 0, 0.1,"
        f" 'ok', NULL, 1.0, 1.0, 1, '{values}', '{{}}' FROM"
        " (WITH RECURSIVE n(value) AS (SELECT 1 UNION ALL SELECT value + 1 FROM n"
        " WHERE value < 20) SELECT value FROM n)",
    )
    return db


def attacks(base: Path, work: Path) -> list[tuple[str, Path, list[str]]]:
    """(name, the hostile journal, the command that reads it)."""
    made = []

    def hostile(name: str, change: Callable[[Path], object], *args: str) -> None:
        directory = work / f"attack-{len(made)}"
        directory.mkdir()
        db = directory / "survey.db"
        shutil.copyfile(base, db)
        change(db)
        made.append((name, db, _cli(*[a.replace("{db}", str(db)) for a in args])))

    casts = ("casts", "--db", "{db}")
    hostile("-wal -> /dev/zero", lambda db: os.symlink("/dev/zero", f"{db}-wal"), *casts)
    hostile("-wal a FIFO", lambda db: os.mkfifo(f"{db}-wal"), *casts)
    hostile("-wal a sparse 3 GiB file", lambda db: _sparse(Path(f"{db}-wal"), 3 << 30), *casts)
    hostile(
        "fixes: an endless view",
        lambda db: _view(db, "fixes", endless),
        "export", "--db", "{db}", "--format", "geojson",
    )  # fmt: skip
    hostile(
        "samples: a 12-way self-join",
        lambda db: _view(db, "samples", self_join("samples")),
        "export", "--db", "{db}", "--format", "csv",
    )  # fmt: skip
    hostile(
        "recover: fixes an endless view",
        lambda db: _view(db, "fixes", endless),
        "recover", "--db", "{db}", "-o", "{db}.new",
    )  # fmt: skip
    hostile(
        "a 200 MB event detail",
        lambda db: _huge(db, "events", "detail_json", 200_000_000, "id = 1"),
        "export", "--db", "{db}", "--format", "csv", "--what", "events",
    )  # fmt: skip
    hostile(
        "a 50 MB text in a sample",
        lambda db: _huge(db, "samples", "phase", 50_000_000, "id = 20"),
        "plot", "--db", "{db}", "--cast", "2", "-o", "{db}.png",
    )  # fmt: skip
    hostile(
        "a 50 MB sonde reading",
        lambda db: _huge(_sonde_rows(db), "sonde_samples", "values_json", 50_000_000, "id = 3"),
        "sonde", "export", "--format", "csv", "--db", "{db}",
    )  # fmt: skip
    return made


_PAGE = """
import json, sys, tempfile, time
from pathlib import Path
from cc_daemon.cli.web import journaldata
from cc_daemon.store import StoreError
db = Path(sys.argv[1])
asks = [lambda: journaldata.surveys(db), lambda: journaldata.events(db, None),
        lambda: journaldata.latest(db, 1.8e9), lambda: journaldata.cast_profile(db, 2)]
times, said = [], ""
for round in range(5):
    for ask in asks:
        start = time.monotonic()
        try:
            ask()
        except StoreError as exc:
            said = str(exc)
        times.append(time.monotonic() - start)
tmp = Path(tempfile.gettempdir())
during = sum(p.lstat().st_size for p in tmp.rglob("*") if p.is_file())
print(json.dumps({"times": times, "said": said, "during": during}))
"""


def _verdict(ok: bool) -> str:
    return "PASS" if ok else "FAIL"


def main() -> int:
    failed = 0
    with tempfile.TemporaryDirectory(prefix="bench-attacks-") as tmp:
        work = Path(tmp)
        base = work / "base.db"
        base_journal(base)
        load = os.getloadavg()[0]
        print(
            f"base: a one-day synthetic survey, {base.stat().st_size / 1e6:.1f} MB;"
            f" load average {load:.1f} on {os.cpu_count()} CPUs"
        )
        print(
            f"{'attack':<32} {'answer':>8} {'CPU':>7} {'exit':>5} {'peak RSS':>9} {'temp left':>10}"
        )
        for name, _, argv in attacks(base, work):
            run = run_child(argv, work)
            exit_text = "hung" if run.code is None else str(run.code)
            ok = (
                run.code == 1
                and run.cpu_s <= CPU_S
                and run.peak_mb <= RSS_MB
                and run.left_bytes == 0
            )
            failed += not ok
            print(
                f"{name:<32} {run.seconds:>7.2f}s {run.cpu_s:>6.2f}s {exit_text:>5}"
                f" {run.peak_mb:>7.0f}MB"
                f" {run.left_bytes:>9}B  {_verdict(ok)}"
            )
            print(f"    {run.said[:180]}")
        failed += _page(base, work)
    print(
        f"(PASS: one line, exit 1, before the {DEADLINE_S:.0f} s deadline, CPU <= {CPU_S:.0f} s,"
        f" peak RSS <= {RSS_MB:.0f} MB, no temporary bytes left)"
    )
    return 1 if failed else 0


def _page(base: Path, work: Path) -> int:
    directory = work / "damaged-page"
    directory.mkdir()
    db = directory / "survey.db"
    shutil.copyfile(base, db)
    _garble(db, 5)
    run = run_child([sys.executable, "-c", _PAGE, str(db)], work, DEADLINE_S * 6)
    if run.code != 0:
        print(f"a damaged journal read as the page reads it: {run.said[:160]}  FAIL")
        return 1
    found = json.loads(run.stdout)
    times = sorted(found["times"][1:])
    later = times[len(times) // 2]
    ok = later <= PAGE_S and run.left_bytes == 0 and found["during"] <= 2 * db.stat().st_size
    print(
        f"a damaged journal read as the page reads it ({len(found['times'])} requests,"
        f" {run.seconds:.1f} s in all): first {found['times'][0]:.2f} s, then median"
        f" {later:.3f} s (max {times[-1]:.3f} s); temporary bytes {found['during']} while"
        f" it ran, {run.left_bytes} after; CPU {run.cpu_s:.1f} s; peak RSS {run.peak_mb:.0f} MB"
        f"  {_verdict(ok)}"
    )
    print(f"    {found['said'][:180]}")
    return int(not ok)


if __name__ == "__main__":
    raise SystemExit(main())
