"""The field page under attack (issue 27): what a legitimate page still gets.

`cc-daemon web` runs as a subprocess, as its unit runs it: a password set, 1,024
descriptors (the unit's LimitNOFILE), its log in JSON on stderr (read whole by a
thread), a status socket served beside it and a journal holding a ten-day survey
(`BENCH_WEB_DAYS`, 10: 864,000 fixes, grown with `tests.webkit.lengthen`).
Meanwhile a logged-in page asks /api/status four times a second on a kept-alive
connection (reconnecting, as a browser does, when the page has closed it), and
each attack runs for `BENCH_WEB_ATTACK_S` (5) seconds:

- idle connections: 1,100 that send nothing, from 40 addresses (127.0.0.2 and
  up), re-opened as soon as the page closes one;
- slow headers: 300 connections sending a request head a byte a second;
- password flood: four clients (four addresses) sending 20 wrong passwords a
  second each, each on a new connection, not waiting for the answers;
- big download: the survey's GeoJSON, read whole as fast as the client can;
- all at once: two GeoJSON downloads (stopped after the phase), idle
  connections and the password flood together.

Printed for each: the legitimate page's answer times (median and worst, and how
many failed), the web process's peak RSS in the phase (VmHWM, reset at its
start through /proc/PID/clear_refs), and the bytes it logged, extrapolated to
an hour; each with PASS/FAIL against the issue's goals: answers within 1 s,
RSS <= 150 MB, log <= 1 MB an hour. The attackers' threads run at nice 10: on
the boat their CPU is another machine's, here they share the page's cores.
`BENCH_WEB_TREE` names another checkout to run the page from (`git worktree add
/tmp/old <commit>`), for a comparison.

    python -m benchmarks.web_attacks      (or: make bench)
"""

from __future__ import annotations

import base64
import contextlib
import http.client
import os
import resource
import selectors
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from benchmarks.flood import peak_rss_mb
from benchmarks.goals import Verdicts
from cc_daemon.ground.logsetup import configure_logging
from tests.browserkit import status_socket
from tests.webkit import REPO, WebProcess, lengthen, make_journal, status

ATTACK_S = float(os.environ.get("BENCH_WEB_ATTACK_S", "5"))
DAYS = float(os.environ.get("BENCH_WEB_DAYS", "10"))
TREE = Path(os.environ["BENCH_WEB_TREE"]) if os.environ.get("BENCH_WEB_TREE") else REPO
NOFILE = 1024  # systemd/cc-daemon-web.service
PASSWORD = "sea-spray 7"
ANSWER_GOAL_S = 1.0
RSS_GOAL_MB = 150.0
LOG_GOAL_PER_HOUR = 1_000_000
IDLE = 1100
SLOW = 300
POLL_S = 0.25
TIMEOUT_S = 5.0  # a legitimate answer later than this counts as failed


def basic(user: str, password: str) -> str:
    return "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()


class Page:
    """A logged-in page polling /api/status on a kept-alive connection."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.times: list[float] = []
        self.failed = 0
        self.stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._conn: http.client.HTTPConnection | None = None

    def ask(self) -> None:
        for attempt in (1, 2):  # a kept-alive connection the page closed: once more
            if self._conn is None:
                self._conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=TIMEOUT_S)
            try:
                self._conn.request(
                    "GET", "/api/status", headers={"Authorization": basic("crew", PASSWORD)}
                )
                answer = self._conn.getresponse()
                answer.read()
                if answer.status != 200:
                    raise OSError(f"status {answer.status}")
                return
            except (OSError, http.client.HTTPException):
                self._conn.close()
                self._conn = None
                if attempt == 2:
                    raise

    def _run(self) -> None:
        while not self.stop.is_set():
            began = time.perf_counter()
            try:
                self.ask()
                self.times.append(time.perf_counter() - began)
            except (OSError, http.client.HTTPException):
                self.failed += 1
            self.stop.wait(max(0.0, POLL_S - (time.perf_counter() - began)))

    def start(self) -> None:
        self._thread.start()

    def finish(self) -> None:
        self.stop.set()
        if self._thread.is_alive():
            self._thread.join(TIMEOUT_S * 3)
        if self._conn is not None:
            self._conn.close()


# ------------------------------------------------------------------ the attacks


def lower_priority() -> None:
    """This thread at nice 10: on the boat an attacker's CPU is another machine's;
    here it shares the page's cores, and must not win them from the page."""
    with contextlib.suppress(OSError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)


class Attack:
    def __init__(self, port: int) -> None:
        self.port = port
        self.stop = threading.Event()
        self.note = ""
        self._threads: list[threading.Thread] = []

    def run(self) -> None:
        raise NotImplementedError

    def start(self) -> None:
        thread = threading.Thread(target=self._lowered, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _lowered(self) -> None:
        lower_priority()
        self.run()

    def finish(self) -> None:
        self.stop.set()
        for thread in self._threads:
            thread.join(60)


def _connect(port: int, source: str) -> socket.socket:
    sock = socket.socket()
    sock.bind((source, 0))
    sock.setblocking(False)
    sock.connect_ex(("127.0.0.1", port))
    return sock


class Holders(Attack):
    """`count` connections from 40 addresses, each sending `head` (then, if
    `drip`, a byte a second), re-opened whenever the page closes one."""

    def __init__(self, port: int, count: int, head: bytes = b"", drip: bool = False) -> None:
        super().__init__(port)
        self.count, self.head, self.drip = count, head, drip
        self.reopened = 0

    def run(self) -> None:
        sources = [f"127.0.0.{n}" for n in range(2, 42)]
        watch = selectors.DefaultSelector()
        made = 0

        def one() -> None:
            nonlocal made
            sock = _connect(self.port, sources[made % len(sources)])
            made += 1
            watch.register(sock, selectors.EVENT_READ | selectors.EVENT_WRITE, [self.head])

        for _ in range(self.count):
            one()
        next_drip = time.monotonic() + 1.0
        try:
            while not self.stop.is_set():
                for key, events in watch.select(0.1):
                    sock = key.fileobj
                    assert isinstance(sock, socket.socket)
                    pending: list[bytes] = key.data
                    if events & selectors.EVENT_READ:  # closed (or answered): again
                        watch.unregister(sock)
                        sock.close()
                        self.reopened += 1
                        one()
                    elif pending[0]:
                        with contextlib.suppress(OSError):
                            pending[0] = pending[0][sock.send(pending[0]) :]
                    else:
                        watch.modify(sock, selectors.EVENT_READ, pending)
                if self.drip and time.monotonic() >= next_drip:
                    next_drip += 1.0
                    for key in list(watch.get_map().values()):
                        with contextlib.suppress(OSError):
                            key.fileobj.send(b"a")  # type: ignore[union-attr]
        finally:
            for key in list(watch.get_map().values()):
                key.fileobj.close()  # type: ignore[union-attr]
            watch.close()
        self.note = f"{self.reopened:,} re-opened after the page closed them"


class PasswordFlood(Attack):
    """Four clients (four addresses), each sending a wrong password every 50 ms on a
    new connection, whether or not the last was answered."""

    def __init__(self, port: int) -> None:
        super().__init__(port)
        self.answers: dict[int, int] = {}
        self._lock = threading.Lock()
        self._pool = ThreadPoolExecutor(80, thread_name_prefix="guess", initializer=lower_priority)

    def guess(self, source: str, n: int) -> None:
        conn = http.client.HTTPConnection(
            "127.0.0.1", self.port, timeout=TIMEOUT_S, source_address=(source, 0)
        )
        try:
            conn.request("GET", "/api/status", headers={"Authorization": basic("x", f"g{n}")})
            status = conn.getresponse().status
        except (OSError, http.client.HTTPException):
            status = 0
        finally:
            conn.close()
        with self._lock:
            self.answers[status] = self.answers.get(status, 0) + 1

    def run(self) -> None:
        n = 0
        next_at = time.monotonic()
        while not self.stop.is_set():
            for client in range(4):
                self._pool.submit(self.guess, f"127.0.0.{60 + client}", n)
                n += 1
            next_at += 0.05
            self.stop.wait(max(0.0, next_at - time.monotonic()))

    def finish(self) -> None:
        super().finish()
        self._pool.shutdown(wait=True)
        self.note = ", ".join(
            f"{n:,} x {s or 'no answer'}" for s, n in sorted(self.answers.items())
        )


class Download(Attack):
    """The survey's GeoJSON, read as fast as we can; `whole`: to its end, else
    until stopped."""

    def __init__(self, port: int, survey: int, whole: bool) -> None:
        super().__init__(port)
        self.survey, self.whole = survey, whole
        self.bytes = 0
        self.took = 0.0
        self.done = threading.Event()

    def run(self) -> None:
        began = time.monotonic()
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=300)
        try:
            conn.request(
                "GET",
                f"/download/survey/{self.survey}.geojson",
                headers={"Authorization": basic("crew", PASSWORD)},
            )
            answer = conn.getresponse()
            while (self.whole or not self.stop.is_set()) and (chunk := answer.read(1 << 20)):
                self.bytes += len(chunk)
        finally:
            conn.close()
            self.took = time.monotonic() - began
            self.done.set()
        self.note = f"{self.bytes / 1e6:,.1f} MB in {self.took:.1f} s"


# ------------------------------------------------------------------ a phase


def phase(
    report: Verdicts,
    name: str,
    web: WebProcess,
    attacks: list[Attack],
    until: Callable[[], bool] | None = None,
) -> None:
    """Run `attacks` with a page polling, for ATTACK_S (or until `until()`), and
    print the page's answers, the peak RSS and the log, against the goals."""
    pid = web.proc.pid
    with contextlib.suppress(OSError):
        Path(f"/proc/{pid}/clear_refs").write_text("5")  # VmHWM from now
    logged_before = len(web.lines)
    page = Page(web.port)
    began = time.monotonic()
    for attack in attacks:
        attack.start()
    time.sleep(0.5)  # the attack under way before the page asks
    page.start()
    while time.monotonic() - began < ATTACK_S or (until is not None and not until()):
        time.sleep(0.1)
    page.finish()
    for attack in attacks:
        attack.finish()
    elapsed = time.monotonic() - began
    rss = peak_rss_mb(pid)
    logged = sum(len(line) for line in web.lines[logged_before:])
    per_hour = logged / elapsed * 3600
    times = page.times or [float("inf")]
    worst = max(times)
    print(f"  -- {name} ({elapsed:.1f} s)", flush=True)
    for attack in attacks:
        if attack.note:
            print(f"         {type(attack).__name__}: {attack.note}", flush=True)
    report.line(
        f"{name}: the page's /api/status",
        f"median {statistics.median(times) * 1000:.1f} ms, worst {worst * 1000:.1f} ms, "
        f"{len(page.times)} answered, {page.failed} failed (<= {ANSWER_GOAL_S:g} s, none failed)",
        worst <= ANSWER_GOAL_S and page.failed == 0,
    )
    report.line(f"{name}: web peak RSS", f"{rss:.1f} MB (<= {RSS_GOAL_MB:g})", rss <= RSS_GOAL_MB)
    report.line(
        f"{name}: log",
        f"{logged:,} bytes in {elapsed:.1f} s: {per_hour / 1e6:.3f} MB an hour "
        f"(<= {LOG_GOAL_PER_HOUR / 1e6:g})",
        per_hour <= LOG_GOAL_PER_HOUR,
    )


@contextlib.contextmanager
def ten_day_survey(directory: Path) -> Iterator[tuple[Path, int]]:
    """A journal whose latest survey lasts DAYS days: (its path, the survey's id)."""
    db = make_journal(directory / "survey.db")  # its latest survey: 30 minutes
    lengthen(db, round(DAYS * 86_400 / 1_800) - 1)
    yield db, 2


def main() -> int:
    print("== the field page under attack (issue 27) ==", flush=True)
    configure_logging("console", "warning")  # the status socket's own lines: not ours to show
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    with contextlib.suppress(ValueError, OSError):  # ours: the attacks' sockets
        resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 8192)), hard))
    report = Verdicts()
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        began = time.monotonic()
        with ten_day_survey(directory) as (db, survey):
            fixes = round(DAYS * 86_400)
            print(
                f"  a {DAYS:g}-day survey (about {fixes:,} fixes) made in "
                f"{time.monotonic() - began:.1f} s; the page from {TREE}",
                flush=True,
            )
            setting = subprocess.run(
                [sys.executable, "-m", "cc_daemon", "web", "--hash-password"],
                input=PASSWORD, capture_output=True, text=True, check=True,
                env={**os.environ, "PYTHONPATH": str(REPO)},
            ).stdout.strip()  # fmt: skip
            config = directory / "cc-daemon.toml"
            config.write_text(f"[web]\n{setting}\n")
            sock = directory / "status.sock"
            with (
                status_socket(sock, status()),
                WebProcess(db, sock, "--config", str(config), nofile=NOFILE, tree=TREE) as web,
            ):
                run_phases(report, web, survey)
                total = sum(len(line) for line in web.log())
                print(f"  the web's whole log: {total:,} bytes", flush=True)
                for line in web.log()[:10]:
                    print(f"         {line.decode(errors='replace').strip()[:160]}", flush=True)
    if report.failed:
        print(f"  goals missed: {'; '.join(report.failed)}", flush=True)
        return 1
    return 0


def run_phases(report: Verdicts, web: WebProcess, survey: int) -> None:
    port = web.port
    login = Page(port)
    began = time.perf_counter()
    login.ask()  # the page logs in once (one scrypt); what follows is remembered
    login.finish()
    print(f"  the first answer with the password: {(time.perf_counter() - began) * 1000:.0f} ms")
    phase(report, "no attack", web, [])
    phase(report, f"{IDLE:,} idle connections", web, [Holders(port, IDLE)])
    head = b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: "
    phase(report, f"{SLOW} slow headers", web, [Holders(port, SLOW, head, drip=True)])
    phase(report, "password flood, 4 x 20/s", web, [PasswordFlood(port)])
    download = Download(port, survey, whole=True)
    phase(report, f"the {DAYS:g}-day GeoJSON", web, [download], until=download.done.is_set)
    phase(
        report,
        "two downloads, idle connections and the flood at once",
        web,
        [
            Download(port, survey, whole=False),
            Download(port, survey, whole=False),
            Holders(port, IDLE),
            PasswordFlood(port),
        ],
    )


if __name__ == "__main__":
    raise SystemExit(main())
