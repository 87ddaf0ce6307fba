"""The daemon's memory under a 1000/s sonar stream (issue 22: RSS <= 50 MiB).

The daemon runs as the service does (a subprocess, the shipped configuration
with `--winch sim`, a JSON log, on a pty pair, bytecode compiled: `benchmarks.goals`'
way of starting it) with its own sonar on a second pty (`CC_DAEMON_SONAR__PORT`).
On that pty's other end the project's simulated Ping1D answers the daemon, and
once the daemon has asked it to stream, the benchmark writes `distance_simple`
frames at 1000 a second (each 10 ms, the frames due by then). After `BENCH_SONAR_RSS_S` seconds
(30 by default) it prints the readings the Ping sent, their rate, the daemon's
peak resident memory (`VmHWM`) and the `R-P` still answered, with PASS/FAIL
against 50 MiB.

    python -m benchmarks.sonar_rss      (or: make bench)
"""

from __future__ import annotations

import asyncio
import json
import os
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.daemon import wait_first_answer
from benchmarks.flood import peak_rss_mb
from benchmarks.goals import daemon_command, daemon_env, stop, warm_bytecode
from cc_daemon.drivers.sonar import ping
from cc_daemon.sim.ping1d import Echo, Ping1DDevice, Ping1DServer
from cc_daemon.sim.pty import PtyPair

SECONDS = float(os.environ.get("BENCH_SONAR_RSS_S", "30"))
LIMIT_MIB = 50.0
PER_S = 1000  # a Ping babbling


def _heard(journal: Path) -> int:
    """Readings the daemon took in: journaled, or counted in its thinning events."""
    with sqlite3.connect(journal) as db:
        (kept,) = db.execute("SELECT count(*) FROM sonar_readings").fetchone()
        thinned = db.execute("SELECT detail_json FROM events WHERE kind = 'sonar_thinned'")
        return int(kept) + sum(int(json.loads(d).get("count", 0)) for (d,) in thinned)


async def _babble(server: Ping1DServer, seconds: float) -> int:
    """`PER_S` readings a second for `seconds`, written as they fall due."""
    frame = ping.encode(ping.DISTANCE_SIMPLE, src=1, dst=0, distance=8219, confidence=100)
    started, sent = time.monotonic(), 0
    while (elapsed := time.monotonic() - started) < seconds:
        due = int(elapsed * PER_S) - sent
        if due > 0:
            server.write(frame * due)
            sent += due
        await asyncio.sleep(0.01)
    return sent


async def _run(directory: Path) -> tuple[int, float, float, float]:
    with PtyPair(directory / "tty") as line, PtyPair(directory / "ttySonar") as sonar:
        device = Ping1DDevice(lambda: Echo(8219, 100), interval_s=3600.0)  # we stream
        server = await Ping1DServer.over_fd(sonar.master_fd, device)
        env = daemon_env() | {"CC_DAEMON_SONAR__PORT": str(sonar.path)}
        proc = await asyncio.to_thread(
            subprocess.Popen,
            daemon_command(directory, line.path),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
            cwd=directory,
        )
        try:
            started = time.monotonic()
            await asyncio.to_thread(wait_first_answer, line.master_fd, started)
            # The simulated Ping's flag, set as the daemon's request arrives: polled.
            while not device.streaming and time.monotonic() - started < 20:  # noqa: ASYNC110
                await asyncio.sleep(0.05)
            since = time.monotonic()
            sent = await _babble(server, SECONDS)
            rate = sent / (time.monotonic() - since)
            peak = peak_rss_mb(proc.pid)
            answered = await asyncio.to_thread(wait_first_answer, line.master_fd, time.monotonic())
        finally:
            await asyncio.to_thread(stop, proc)
            await server.close()
        return sent, rate, peak, answered


def main() -> int:
    warm_bytecode([Path(__file__).resolve().parent.parent])
    with tempfile.TemporaryDirectory() as tmp:
        sent, rate, peak, answered_s = asyncio.run(_run(Path(tmp)))
        heard = _heard(Path(tmp) / "journal.db")
    passed = peak <= LIMIT_MIB and rate >= 0.95 * PER_S
    print(
        f"  {'PASS' if passed else 'FAIL'}  RSS under a sonar stream: {sent} readings in "
        f"{SECONDS:.0f} s ({rate:.0f}/s; the daemon journaled or counted {heard} in all), "
        f"peak {peak:.1f} MiB (<= {LIMIT_MIB:.0f}); R-P after it in {answered_s * 1e3:.1f} ms"
    )
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
