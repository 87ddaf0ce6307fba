"""Sonde benchmark: one sample at 9600 baud, the sampling beat's jitter, and what polling
costs the autopilot's P-S replies.

- one sample: the real reader against the simulated sonde on a pty, the line
  paced at 9600 baud by the simulator's bridge (a pty has no baud rate);
- cadence: the daemon's sampling duty in a cast, 60 readings on absolute
  deadlines; jitter is each request's distance from its ideal time;
- P-S latency: the daemon as a subprocess with `sonde.backend = "modbus"` polling
  `cc-daemon simulate-sonde` (a process of its own, like a real device)
  every 0.25 s (four times the service's rate, so more requests meet a read)
  against the same daemon with no sonde; P-S requests 5 ms apart for ~10 s.

    python -m benchmarks sonde      (or: make bench)
"""

from __future__ import annotations

import asyncio
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.daemon import (
    REPO,
    daemon_config,
    drain,
    measure_latency,
    percentile,
    start_daemon,
    wait_first_answer,
)
from cc_daemon.config import Settings
from cc_daemon.config.sonde import SondeSettings
from cc_daemon.daemon.sonde import SondeDuty
from cc_daemon.drivers.sonde.reader import SondeReader
from cc_daemon.ground.clock import SystemClock
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.sonde import SimulatedSonde
from cc_daemon.store import JournalReader

SAMPLES = 50
BEATS = 60
PERIOD_S = 0.5  # the beat (1 s in service): 60 beats in 30 s, same scheduling path
REQUESTS = 2000
SPACING_S = 0.005
# One request of 30 registers: 8 bytes out, 5 + 60 back, ten bits a byte at 9600 baud.
WIRE_MS = (8 + 65) * 10 / 9600 * 1000


class _InCast:
    phase = "descending"
    cast_id = 1
    probe_depth_m = 2.0


async def one_sample(path: Path) -> list[float]:
    reader = SondeReader(SondeSettings(backend="modbus", port=str(path)))
    durations = []
    try:
        for _ in range(SAMPLES):
            reading = await reader.read()
            assert reading.status == "ok", reading
            durations.append(reading.duration_s * 1000)
    finally:
        await reader.close()
    return durations


async def cadence(path: Path) -> list[float]:
    settings = Settings.model_validate(
        {
            "sonde": {
                "backend": "modbus",
                "port": str(path),
                "period_s": PERIOD_S,
                "timeout_s": 0.2,
                "retries": 0,
            }
        }
    )
    duty = SondeDuty(
        settings,
        clock=SystemClock(),
        journal=None,
        view=_InCast,
        on_bottom_contact=lambda depth: None,
    )
    task = asyncio.create_task(duty._sample_forever())
    times: list[float] = []
    try:
        while len(times) < BEATS:
            await asyncio.sleep(PERIOD_S / 5)
            latest = duty.latest
            if latest is not None and (not times or latest.mono_s != times[-1]):
                times.append(latest.mono_s)
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        await duty.reader.close()
    return [abs(t - (times[0] + i * PERIOD_S)) * 1000 for i, t in enumerate(times)]


def ps_latency(directory: Path, with_sonde: bool) -> tuple[list[float], int]:
    """R-P latencies, and how many sonde readings the daemon journaled meanwhile."""
    name = "ttyWith" if with_sonde else "ttyWithout"
    pty = PtyPair(directory / name)
    os.set_blocking(pty.master_fd, True)
    config = daemon_config(directory, pty.path, report_period_s=10.0)  # the most allowed
    if with_sonde:
        with config.open("a") as f:
            f.write(
                f'[sonde]\nbackend = "modbus"\nport = "{directory / "ttyBenchSonde"}"\n'
                "period_s = 0.25\nidle_period_s = 0.25\ntimeout_s = 0.2\nretries = 0\n"
            )
    sim = None
    if with_sonde:
        # The simulated sonde in a process of its own, as a real one is a device of its
        # own: in the daemon's process its thread would compete for the GIL.
        sonde_path = directory / "ttyBenchSonde"
        sim = subprocess.Popen(
            [sys.executable, "-m", "cc_daemon", "simulate-sonde", "--port", str(sonde_path),
             "--depth", "2"],
            stdout=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=str(REPO)),
        )  # fmt: skip
        assert sim.stdout is not None
        sim.stdout.readline()
    proc = start_daemon(config)
    try:
        wait_first_answer(pty.master_fd, time.monotonic(), timeout=20)
        drain(pty.master_fd)
        time.sleep(2.0)  # let the sonde's first readings start
        # Spread over ~10 s so the requests meet the sonde's reads (every 0.25 s, ~80 ms each).
        result: list[float] = []
        for _ in range(REQUESTS):
            result += measure_latency(pty.master_fd, 1)["R-P"]
            time.sleep(SPACING_S)
        drain(pty.master_fd, 0.2)
        proc.send_signal(signal.SIGINT)
        proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        if sim is not None:
            sim.send_signal(signal.SIGINT)
            sim.wait(10)
        pty.close()
    with JournalReader(directory / "journal.db") as reader:
        readings = len(reader.sonde_samples())
    return result, readings


def main() -> int:
    print("== sonde: one sample at 9600 baud, sampling jitter, P-S latency with polling ==")
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        with SimulatedSonde(directory / "ttySONDE", line_out=lambda: 2.0) as sim:
            durations = asyncio.run(one_sample(sim.path))
            jitter = asyncio.run(cadence(sim.path))
        # Interleaved, twice each: the machine's own noise moves p99 by milliseconds.
        without: list[float] = []
        with_sonde: list[float] = []
        readings = 0
        for _ in range(2):
            without += ps_latency(directory, with_sonde=False)[0]
            got, readings = ps_latency(directory, with_sonde=True)
            with_sonde += got

    ok = True

    def verdict(passed: bool) -> str:
        nonlocal ok
        ok = ok and passed
        return "PASS" if passed else "FAIL"

    print(
        f"one sample (30 registers, one request) over {SAMPLES}: median "
        f"{statistics.median(durations):.1f} ms, p99 {percentile(durations, 99):.1f} ms "
        f"(wire time alone {WIRE_MS:.1f} ms; the old program's 7 requests: "
        f"{7 * (8 + 9) * 10 / 9600 * 1000:.0f} ms of wire plus 7 turnarounds)"
    )
    p99 = percentile(jitter, 99)
    print(
        f"sampling beat over {BEATS} readings ({PERIOD_S:g} s period): p99 |request - ideal| "
        f"{p99:.2f} ms (<= 5) {verdict(p99 <= 5)}, max {max(jitter):.2f} ms"
    )
    w50, w99 = percentile(without, 50), percentile(without, 99)
    s50, s99 = percentile(with_sonde, 50), percentile(with_sonde, 99)
    print(
        f"P-S reply latency over 2 x {REQUESTS} requests (ms): no sonde p50 {w50:.3f} p99 {w99:.3f}"
        f" | sonde polling p50 {s50:.3f} p99 {s99:.3f} | p99 {s99 - w99:+.3f} (<= 0.5) "
        f"{verdict(s99 - w99 <= 0.5)} ({readings} sonde readings journaled meanwhile)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
