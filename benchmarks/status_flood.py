"""Status socket benchmark: what hostile status clients cost the autopilot's link.

The daemon runs as a subprocess on a pty pair with its status socket on. The
autopilot side asks S -> R-P continuously, first alone, then while threads
hammer the socket: 1000 connections that never read (one in ten also sending
garbage), then well-behaved readers as fast as they can. Printed: R-P latency
(median, p99, max) in each phase, documents served per second, the document's
size, and what the flood's clients got.

    python -m benchmarks.status_flood      (or: make bench)
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path

from benchmarks.daemon import (
    daemon_config,
    drain,
    percentile,
    read_exactly,
    start_daemon,
    wait_first_answer,
)
from cc_daemon.cli.status.client import read_status
from cc_daemon.core.protocol import ProbePositionRequest, encode
from cc_daemon.sim.pty import PtyPair

FLOOD = 1000


def latencies(fd: int, seconds: float) -> list[float]:
    frame = encode(ProbePositionRequest(72))
    out: list[float] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        os.write(fd, frame)
        began = time.perf_counter_ns()
        read_exactly(fd, 8, 5.0)
        out.append((time.perf_counter_ns() - began) / 1e6)
    return out


def describe(name: str, values: list[float]) -> None:
    print(
        f"  R-P {name:<22} n={len(values):5d}  median {statistics.median(values):6.2f} ms"
        f"  p99 {percentile(values, 99):6.2f} ms  max {max(values):7.2f} ms"
    )


def flood(path: Path, result: dict[str, float]) -> None:
    held: list[socket.socket] = []
    began = time.monotonic()
    for i in range(FLOOD):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            s.connect(str(path))
        except OSError:
            s.close()
            continue
        if i % 10 == 0:
            s.setblocking(False)
            # Answered and closed already (the document is written at accept): EPIPE.
            with contextlib.suppress(BlockingIOError, BrokenPipeError, ConnectionResetError):
                s.send(os.urandom(8192))
        held.append(s)
    result["open_s"] = time.monotonic() - began
    answered = 0
    for s in held:
        s.setblocking(True)
        s.settimeout(5)
        with contextlib.suppress(OSError):  # reset: closed unanswered
            answered += bool(s.recv(65536))
        s.close()
    result["answered"], result["held"] = answered, len(held)


def readers(path: Path, seconds: float, result: dict[str, float]) -> None:
    served = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        read_status(path)
        served += 1
    result["per_s"] = served / seconds


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp, PtyPair(Path(tmp) / "tty") as pty:
        directory = Path(tmp)
        config = daemon_config(directory, pty.path)
        sock = directory / "status.sock"
        config.write_text(config.read_text() + f'[status]\npath = "{sock}"\n')
        proc = start_daemon(config)
        try:
            wait_first_answer(pty.master_fd, time.monotonic())
            drain(pty.master_fd)
            while not sock.exists():
                time.sleep(0.05)
            size = len(json.dumps(read_status(sock)))
            describe("calm", latencies(pty.master_fd, 2.0))
            got: dict[str, float] = {}
            thread = threading.Thread(target=flood, args=(sock, got))
            thread.start()
            describe(f"{FLOOD} hostile clients", latencies(pty.master_fd, 2.0))
            thread.join()
            thread = threading.Thread(target=readers, args=(sock, 2.0, got))
            thread.start()
            describe("readers flat out", latencies(pty.master_fd, 2.0))
            thread.join()
        finally:
            proc.terminate()
            proc.wait(30)
    print(
        f"  flood: {FLOOD} connections opened in {got['open_s']:.2f} s, {got['held']:.0f} held,"
        f" {got['answered']:.0f} got their document"
    )
    print(f"  readers: {got['per_s']:.0f} documents/s; a document is {size} bytes of JSON")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
