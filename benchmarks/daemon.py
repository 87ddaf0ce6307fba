"""Daemon benchmark: reply latency, depth-report cadence, CPU, memory, start-up.

Everything is measured over a pty pair against the daemon as a subprocess,
beside a floor measured in the same run: a bare responder (a few lines of
blocking os.read/os.write, no asyncio, no parsing) on the same kind of pty.

    python -m benchmarks daemon      (or: make bench)
"""

from __future__ import annotations

import itertools
import os
import select
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cc_daemon.core.protocol import (
    ProbePositionRequest,
    StartMeasuring,
    Telemetry,
    encode,
)
from cc_daemon.sim.pty import PtyPair

REQUESTS = 2000
REPORTS = 60
REPO = Path(__file__).resolve().parent.parent

BARE_RESPONDER = """
import os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
import tty; tty.setraw(fd)
reply_s = bytes.fromhex("52 50 00 48 00 00 00 EA")
reply_m = bytes.fromhex("52 4F 00 48 00 E9")
buf = b""
os.write(1, b"ready\\n")
while True:
    buf += os.read(fd, 64)
    while len(buf) >= 6:
        if buf[1:2] == b"S":
            os.write(fd, reply_s); buf = buf[6:]
        elif len(buf) >= 25:
            os.write(fd, reply_m); buf = buf[25:]
        else:
            break
"""


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q / 100 * (len(ordered) - 1)))]


def read_exactly(fd: int, n: int, timeout: float = 2.0) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout
    while len(out) < n:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            raise TimeoutError(f"got {out.hex(' ')} of {n} bytes")
        out += os.read(fd, n - len(out))
    return out


def drain(fd: int, quiet_s: float = 0.05) -> None:
    while select.select([fd], [], [], quiet_s)[0]:
        os.read(fd, 4096)


def station() -> StartMeasuring:
    return StartMeasuring(72, -37260579, 404506308, 702385, 30_000, 100)


def measure_latency(fd: int, requests: int) -> dict[str, list[float]]:
    """Alternate S and M; time from the request's last byte written to the reply read."""
    s_frame, m_frame = encode(ProbePositionRequest(72)), encode(station())
    out: dict[str, list[float]] = {"R-P": [], "R-O": []}
    for i in range(requests):
        frame, name, size = (s_frame, "R-P", 8) if i % 2 == 0 else (m_frame, "R-O", 6)
        os.write(fd, frame)
        began = time.perf_counter_ns()
        reply = read_exactly(fd, size)
        out[name].append((time.perf_counter_ns() - began) / 1e6)
        assert reply[:2] == (b"RP" if name == "R-P" else b"RO"), reply
    return out


def daemon_config(directory: Path, link: Path, report_period_s: float = 1.0) -> Path:
    config = directory / f"cc-daemon-{link.name}.toml"
    config.write_text(
        f'[serial]\nport = "{link}"\n[store]\npath = "{directory / "journal.db"}"\n'
        "[winch]\nmax_line_m = 40.0\n[winch.sim]\nspeed_m_s = 0.25\n"
        "[cast]\ntarget_depth_m = 20.0\nbottom_dwell_s = 600.0\nmax_duration_s = 900.0\n"
        f"rearm_s = 0.0\nreport_period_s = {report_period_s}\n"
    )
    return config


def start_daemon(config: Path) -> subprocess.Popen[bytes]:
    # The benchmarks drive the simulated winch on purpose: asked for in so many
    # words, as the daemon requires outside --simulate.
    env = dict(
        os.environ, PYTHONPATH=str(REPO), CC_DAEMON_WINCH__SIM__ALLOW_OUTSIDE_SIMULATION="true"
    )
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "cc_daemon",
            "--config",
            str(config),
            "--log-level",
            "warning",
            "--log-format",
            "json",
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )


def wait_first_answer(fd: int, started: float, timeout: float = 10.0) -> float:
    """Ask S every 10 ms until the daemon answers; seconds since `started`."""
    frame = encode(ProbePositionRequest(1))
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        os.write(fd, frame)
        if select.select([fd], [], [], 0.01)[0]:
            try:
                read_exactly(fd, 8, 0.5)
            except TimeoutError:
                continue
            return time.monotonic() - started
    raise TimeoutError("the daemon never answered")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def survey_cadence(fd: int, pid: int) -> tuple[list[float], float, float, float]:
    """A cast with 1 Hz telemetry and an S every 5 s; R-M arrival times, CPU, RSS."""
    drain(fd)
    os.write(fd, encode(station()))
    read_exactly(fd, 6)  # R-O
    ack_at = time.monotonic()
    cpu0, t0 = cpu_seconds(pid), time.monotonic()
    reports: list[float] = []
    buf = b""
    next_t = ack_at + 0.5
    tick = 0
    while len(reports) < REPORTS:
        timeout = max(0.0, next_t - time.monotonic())
        if select.select([fd], [], [], timeout)[0]:
            now = time.monotonic()
            buf += os.read(fd, 256)
            while len(buf) >= 6:
                if buf[:2] == b"RM" and len(buf) >= 8:
                    reports.append(now - ack_at)
                    buf = buf[8:]
                elif buf[:2] == b"RP" and len(buf) >= 8:
                    buf = buf[8:]
                elif buf[:2] == b"RO":
                    buf = buf[6:]
                elif len(buf) < 8:
                    break
                else:
                    buf = buf[1:]
        if time.monotonic() >= next_t:
            tick += 1
            frame = (
                ProbePositionRequest(tick)
                if tick % 5 == 0
                else Telemetry(tick, -37260579, 404506308, 702385, 30_000, 100)
            )
            os.write(fd, encode(frame))
            next_t += 1.0
    cpu = cpu_seconds(pid) - cpu0
    wall = time.monotonic() - t0
    return reports, cpu, wall, rss_mb(pid)


def main() -> int:
    print("== daemon: latency, cadence, CPU, memory, start-up (pty pair, subprocess) ==")
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        # --- the floor: a bare responder on a pty
        floor_pty = PtyPair(directory / "ttyFloor")
        os.set_blocking(floor_pty.master_fd, True)
        bare = subprocess.Popen(
            [sys.executable, "-c", BARE_RESPONDER, str(floor_pty.path)],
            stdout=subprocess.PIPE,
        )
        assert bare.stdout is not None
        bare.stdout.readline()
        floor = measure_latency(floor_pty.master_fd, REQUESTS)
        bare.kill()
        bare.wait()
        floor_pty.close()

        # --- the daemon
        pty = PtyPair(directory / "ttyAP")
        os.set_blocking(pty.master_fd, True)
        started = time.monotonic()
        # No depth reports during the latency run (a few seconds, under the longest
        # period allowed): only replies on the line.
        proc = start_daemon(daemon_config(directory, pty.path, report_period_s=10.0))
        try:
            startup = wait_first_answer(pty.master_fd, started)
            drain(pty.master_fd)
            ours = measure_latency(pty.master_fd, REQUESTS)
            drain(pty.master_fd, 0.2)
            # End the long cast the latency M frames started, then survey.
            proc.send_signal(signal.SIGINT)  # graceful: the probe comes home first
            proc.wait(120)
            pty.close()
            pty = PtyPair(directory / "ttyAP2")
            os.set_blocking(pty.master_fd, True)
            proc = start_daemon(daemon_config(directory, pty.path))
            wait_first_answer(pty.master_fd, time.monotonic())
            reports, cpu, wall, rss = survey_cadence(pty.master_fd, proc.pid)
        finally:
            proc.kill()
            proc.wait()
            pty.close()

    ok = True

    def verdict(passed: bool) -> str:
        nonlocal ok
        ok = ok and passed
        return "PASS" if passed else "FAIL"

    print(f"reply latency over {REQUESTS} requests (ms), last byte written -> whole reply read")
    for name in ("R-P", "R-O"):
        fp50, fp99 = percentile(floor[name], 50), percentile(floor[name], 99)
        dp50, dp99 = percentile(ours[name], 50), percentile(ours[name], 99)
        print(
            f"  {name}: floor p50 {fp50:.3f} p99 {fp99:.3f} | daemon p50 {dp50:.3f} "
            f"p99 {dp99:.3f} | p50 +{dp50 - fp50:.3f} (<= 0.3) {verdict(dp50 - fp50 <= 0.3)}, "
            f"p99 +{dp99 - fp99:.3f} (<= 2.0) {verdict(dp99 - fp99 <= 2.0)}"
        )
    periods = [b - a for a, b in itertools.pairwise(reports)]
    jitter = [abs(p - 1.0) * 1000 for p in periods]
    drift = (reports[-1] - REPORTS * 1.0) * 1000
    p99_jitter = percentile(jitter, 99)
    print(
        f"R-M cadence over {REPORTS} reports: mean period {statistics.fmean(periods):.4f} s, "
        f"p99 |period - 1 s| {p99_jitter:.2f} ms (<= 5) {verdict(p99_jitter <= 5)}, "
        f"60th report {drift:+.2f} ms from ideal (<= 5) {verdict(abs(drift) <= 5)}"
    )
    share = cpu / wall * 100
    print(
        f"CPU during a {wall:.0f} s survey (1 frame/s + a cast): {cpu:.2f} s = {share:.2f} % "
        f"of one core (<= 0.5 %) {verdict(share <= 0.5)}"
    )
    print(f"resident memory: {rss:.1f} MB (<= 50) {verdict(rss <= 50)}")
    print(f"process start to answering S: {startup:.3f} s (<= 1.5) {verdict(startup <= 1.5)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
