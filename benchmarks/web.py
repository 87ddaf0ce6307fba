"""Field page benchmark: the page's first load, and what ten phones cost the daemon.

The daemon runs as a subprocess on a pty pair with its status socket on, and
`cc-daemon web` as another, on a journal holding a synthetic 2-hour survey. The
autopilot side asks S -> R-P continuously, first with no page open, then while
ten clients poll /api/status once a second (what ten open pages do), then while
ten clients poll it as fast as they can. Printed: the first load's bytes (the
page, its CSS and JS, and the first status and survey answers), R-P latency
(median, p99, max) in each phase, and the page's own /api/status answer times,
also while eight clients download the survey's CSV over and over (journal work,
queued `JOURNAL_AT_ONCE` at a time: the status must not wait behind it).

    python -m benchmarks.web      (or: make bench)
"""

from __future__ import annotations

import json
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from benchmarks.daemon import daemon_config, drain, percentile, start_daemon, wait_first_answer
from benchmarks.status_flood import describe, latencies
from cc_daemon.cli.web.server import JOURNAL_AT_ONCE
from cc_daemon.sim.pty import PtyPair
from cc_daemon.store import Journal
from cc_daemon.store.synthetic import FakeClock, write_survey

CLIENTS = 10
PHASE_S = 10.0
DOWNLOADERS = 8
FIRST_LOAD = [
    "",
    "static/page.css",
    "static/page.js",
    "static/words.js",
    "static/draw.js",
    "static/today.js",
    "static/dom.js",
    "static/science.js",
    "api/status",
    "api/latest",
    "api/surveys",
]


def get(url: str, timeout: float = 5.0) -> bytes:
    with urllib.request.urlopen(url, timeout=timeout) as answer:
        body: bytes = answer.read()
    return body


def start_web(sock: Path, db: Path) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cc_daemon", "web", "--listen", "127.0.0.1:0",
         "--socket", str(sock), "--db", str(db)],
        stdin=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stderr is not None
    for line in proc.stderr:
        found = re.search(r"(http://127\.0\.0\.1:\d+/)", line)
        if found:
            return proc, found.group(1)
    raise RuntimeError(f"cc-daemon web did not start (exit {proc.poll()})")


def pollers(url: str, period_s: float, stop: threading.Event, times: list[float]) -> None:
    def one() -> None:
        while not stop.is_set():
            began = time.perf_counter()
            get(url + "api/status")
            took = time.perf_counter() - began
            times.append(took * 1000)
            stop.wait(max(0.0, period_s - took))

    threads = [threading.Thread(target=one) for _ in range(CLIENTS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()


def status_beside_downloads(url: str, survey: int) -> None:
    """The page's /api/status answer times while DOWNLOADERS clients download the
    survey's CSV over and over, JOURNAL_AT_ONCE at a time (tests/test_web.py checks
    the status is answered while every journal turn is stuck; this is the figure)."""
    stop = threading.Event()
    download_ms: list[float] = []

    def download() -> None:
        while not stop.is_set():
            began = time.perf_counter()
            get(url + f"download/survey/{survey}.csv", timeout=60)
            download_ms.append((time.perf_counter() - began) * 1000)

    threads = [threading.Thread(target=download) for _ in range(DOWNLOADERS)]
    for t in threads:
        t.start()
    time.sleep(0.5)
    times: list[float] = []
    end = time.monotonic() + PHASE_S
    while time.monotonic() < end:  # 5 a second: past the 0.5 s sharing, some read anew
        began = time.perf_counter()
        get(url + "api/status")
        times.append((time.perf_counter() - began) * 1000)
        time.sleep(0.2)
    stop.set()
    for t in threads:
        t.join()
    print(
        f"  /api/status beside {DOWNLOADERS} CSV downloads ({JOURNAL_AT_ONCE} at a time, "
        f"{len(download_ms)} done, median {statistics.median(download_ms):.0f} ms each): "
        f"n={len(times)} median {statistics.median(times):.2f} ms "
        f"p99 {percentile(times, 99):.2f} ms max {max(times):.2f} ms"
    )


def science_made(url: str, survey: int) -> None:
    """The day's science: its first making (the map and the profiles, with their
    files), then the same answer kept."""
    times = []
    for _ in range(2):
        began = time.perf_counter()
        body = get(url + f"api/surveys/{survey}/science", timeout=600)
        times.append((time.perf_counter() - began) * 1000)
    doc = json.loads(body)
    parts = ", ".join(f"{k}: {doc[k].get('why', 'made')}" for k in ("map", "profiles"))
    print(
        f"  the day's science: made in {times[0]:.0f} ms, then kept: {times[1]:.1f} ms;"
        f" {len(body)} bytes ({parts})"
    )


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp, PtyPair(Path(tmp) / "tty") as pty:
        directory = Path(tmp)
        config = daemon_config(directory, pty.path)
        sock, db = directory / "status.sock", directory / "survey.db"
        config.write_text(config.read_text() + f'[status]\npath = "{sock}"\n')
        clock = FakeClock()
        journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
        journal.open()
        write_survey(journal, clock, duration_s=7200, cast_every_s=600)
        journal.close()
        proc = start_daemon(config)
        web, url = start_web(sock, db)
        try:
            wait_first_answer(pty.master_fd, time.monotonic())
            drain(pty.master_fd)
            while not sock.exists():
                time.sleep(0.05)
            sizes = {path or "/": len(get(url + path)) for path in FIRST_LOAD}
            # ...then what the page asks on its own: the latest survey and its last cast.
            survey = json.loads(get(url + "api/surveys"))["surveys"][-1]["id"]
            casts = json.loads(get(url + f"api/surveys/{survey}/casts"))["casts"]
            measured = [c["id"] for c in casts if c["samples"]][-1]
            for path in (f"api/surveys/{survey}/casts", f"api/events?survey={survey}",
                         f"api/casts/{measured}/profile"):  # fmt: skip
                sizes[path.split("?")[0]] = len(get(url + path))
            print(
                f"  first load: {sum(sizes.values())} bytes ("
                + ", ".join(f"{k} {v}" for k, v in sizes.items())
                + ")"
            )
            science_made(url, survey)
            describe("no page open", latencies(pty.master_fd, PHASE_S))
            for name, period in (("10 pages at 1 Hz", 1.0), ("10 clients flat out", 0.0)):
                stop, times = threading.Event(), []
                thread = threading.Thread(target=pollers, args=(url, period, stop, times))
                thread.start()
                time.sleep(0.5)
                describe(name, latencies(pty.master_fd, PHASE_S))
                stop.set()
                thread.join()
                print(
                    f"  /api/status {name}: n={len(times)} median "
                    f"{statistics.median(times):.2f} ms p99 {percentile(times, 99):.2f} ms"
                )
            status_beside_downloads(url, survey)
        finally:
            web.terminate()
            web.wait(10)
            assert web.stderr is not None
            web.stderr.close()
            proc.terminate()
            proc.wait(30)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
