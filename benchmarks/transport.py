"""The serial transport, measured: what a P-S costs through each way of reading a port.

Three responders, each a subprocess answering P-S with R-P through our parser
and encoder on a pty (the same as the daemon's link, without the daemon):

- `pyserial-asyncio` (what the link used): `serial_asyncio.create_serial_connection`;
- `pyserial-asyncio-fast`, its maintained drop-in, if importable (`pip install
  pyserial-asyncio-fast`, or `BENCH_PSAF_PATH` naming an unpacked wheel);
- `add_reader`: the port opened and set up by pyserial, then a plain reader on
  its fd (`loop.add_reader`, `os.read`, `os.write`): what `drivers/link.py` does now.

For each: R-P p50/p99 over `REQUESTS` S (one at a time, as the autopilot asks)
and the responder's CPU per request (its threads' schedstat run time). Rounds
are interleaved (A B C A B C ...) so a busy neighbour loads them alike; the
medians over the rounds are printed, beside the pty floor (a bare responder).

    python -m benchmarks.transport
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.daemon import BARE_RESPONDER, percentile, read_exactly
from cc_daemon.core.protocol import ProbePositionRequest, encode
from cc_daemon.sim.pty import PtyPair

REPO = Path(__file__).resolve().parent.parent
REQUESTS = int(os.environ.get("BENCH_TRANSPORT_REQUESTS", "2000"))
ROUNDS = int(os.environ.get("BENCH_TRANSPORT_ROUNDS", "3"))

RESPONDER = """
import asyncio, os, sys
from cc_daemon.core.protocol import Parser, ProbePosition, ProbePositionRequest, Sender, encode

kind, path = sys.argv[1], sys.argv[2]


class Answer(asyncio.Protocol):
    def __init__(self):
        self.parser = Parser(Sender.AUTOPILOT)

    def connection_made(self, transport):
        self.transport = transport

    def data_received(self, data):
        for m in self.parser.feed(data):
            if isinstance(m, ProbePositionRequest):
                self.transport.write(encode(ProbePosition(m.timestamp_s, 0)))


async def main():
    loop = asyncio.get_running_loop()
    if kind == "add_reader":
        import serial

        port = serial.Serial(path, 9600, timeout=0)
        fd = port.fileno()
        os.set_blocking(fd, False)
        parser = Parser(Sender.AUTOPILOT)

        def readable():
            for m in parser.feed(os.read(fd, 4096)):
                if isinstance(m, ProbePositionRequest):
                    os.write(fd, encode(ProbePosition(m.timestamp_s, 0)))

        loop.add_reader(fd, readable)
    else:
        name = "serial_asyncio" if kind == "pyserial-asyncio" else "serial_asyncio_fast"
        module = __import__(name)
        await module.create_serial_connection(loop, Answer, path, baudrate=9600)
    print("ready", flush=True)
    await asyncio.Event().wait()


asyncio.run(main())
"""


def run_ns(pid: int) -> int:
    return sum(
        int((task / "schedstat").read_text().split()[0])
        for task in Path(f"/proc/{pid}/task").iterdir()
    )


def latencies(fd: int, requests: int) -> list[float]:
    frame = encode(ProbePositionRequest(72))
    out = []
    for _ in range(requests):
        os.write(fd, frame)
        start = time.perf_counter_ns()
        read_exactly(fd, 8)
        out.append((time.perf_counter_ns() - start) / 1e6)
    return out


def one_round(directory: Path, kind: str, env: dict[str, str]) -> tuple[list[float], float]:
    pty = PtyPair(directory / f"tty-{kind}")
    os.set_blocking(pty.master_fd, True)
    script = BARE_RESPONDER if kind == "floor" else RESPONDER
    argv = [sys.executable, "-c", script] + ([] if kind == "floor" else [kind]) + [str(pty.path)]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, env=env)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()
        latencies(pty.master_fd, 50)  # warm up
        before = run_ns(proc.pid)
        lat = latencies(pty.master_fd, REQUESTS)
        cpu_us = (run_ns(proc.pid) - before) / 1e3 / REQUESTS
        return lat, cpu_us
    finally:
        proc.kill()
        proc.wait()
        pty.close()


def available(kind: str, env: dict[str, str]) -> bool:
    module = {"pyserial-asyncio": "serial_asyncio", "pyserial-asyncio-fast": "serial_asyncio_fast"}
    if kind not in module:
        return True
    probe = subprocess.run(
        [sys.executable, "-c", f"import {module[kind]}"], env=env, capture_output=True, check=False
    )
    return probe.returncode == 0


def main() -> int:
    print(f"== transport: R-P latency and CPU per P-S, {ROUNDS} interleaved rounds ==")
    env = dict(os.environ)
    paths = [str(REPO)] + (
        [os.environ["BENCH_PSAF_PATH"]] if "BENCH_PSAF_PATH" in os.environ else []
    )
    env["PYTHONPATH"] = os.pathsep.join(paths)
    kinds = [
        k
        for k in ("floor", "pyserial-asyncio", "pyserial-asyncio-fast", "add_reader")
        if available(k, env)
    ]
    results: dict[str, list[tuple[list[float], float]]] = {k: [] for k in kinds}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(ROUNDS):
            for kind in kinds:
                results[kind].append(one_round(Path(tmp), kind, env))
    for kind in ("floor", "pyserial-asyncio", "pyserial-asyncio-fast", "add_reader"):
        if kind not in results:
            print(f"  {kind:22} not importable here: skipped")
            continue
        rounds = results[kind]
        p50 = statistics.median(percentile(lat, 50) for lat, _ in rounds)
        p99 = statistics.median(percentile(lat, 99) for lat, _ in rounds)
        cpu = statistics.median(c for _, c in rounds)
        print(
            f"  {kind:22} R-P p50 {p50:.3f} ms, p99 {p99:.3f} ms; "
            f"CPU {cpu:.0f} µs per P-S (medians of {len(rounds)} rounds)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
