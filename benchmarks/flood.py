"""Flood benchmark: a babbling autopilot sending valid P-T at the pty's full speed.

The daemon runs as a subprocess on a pty pair with its default telemetry rate
(`store.telemetry_rate_hz` = 2). One thread writes P-T frames as fast as the
pty takes them, with a P-S after every chunk of about 4 kB (every few ms);
another reads the replies and times each R-P from its request. Reported:

- resident memory (peak, VmHWM) against the 50 MB budget;
- journal growth per minute against 1 MB/min: on disk during the flood (the file
  and its write-ahead log, which grows by whole pages per commit until its 4 MB
  checkpoint and is then reused), and the data itself (the file after a final
  checkpoint, less an empty journal, over the whole run), with the fixes
  journaled and counted as thinned;
- P-S reply latency (p50, p99, max) under the flood, and that every P-S was answered.

    python -m benchmarks.flood      (or: make bench; BENCH_FLOOD_S=10 for a short run)
"""

from __future__ import annotations

import os
import select
import signal
import sqlite3
import tempfile
import threading
import time
from pathlib import Path

from benchmarks.daemon import percentile, rss_mb, start_daemon, wait_first_answer
from cc_daemon.core.protocol import ProbePositionRequest, Telemetry, encode
from cc_daemon.sim.pty import PtyPair
from cc_daemon.store import Journal

FLOOD_S = float(os.environ.get("BENCH_FLOOD_S", "60"))
WARMUP_S = 3.0
CHUNK_FRAMES = 160  # 160 P-T frames of 25 bytes: 4 kB between two P-S


def flood_config(directory: Path, link: Path) -> Path:
    config = directory / "flood.toml"
    config.write_text(f'[serial]\nport = "{link}"\n[store]\npath = "{directory / "journal.db"}"\n')
    return config


def peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def empty_journal_bytes(directory: Path) -> int:
    """The size of a journal with nothing in it yet (its schema, one session)."""
    path = directory / "empty.db"
    with Journal(path):
        pass
    with sqlite3.connect(path) as db:
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
    return path.stat().st_size


def journal_bytes(directory: Path) -> int:
    return sum(
        path.stat().st_size
        for path in directory.glob("journal.db*")
        if path.name != "journal.db-shm"
    )


def write_all(fd: int, data: bytes) -> None:
    """Whole frames only: a pty may take part of a write."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class Flood:
    """The writer and reader threads, and what they saw."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.stop = threading.Event()
        self.written = threading.Event()  # the writer has sent its last frame
        self.asked: list[float] = []
        self.answered: list[float] = []
        self.frames_sent = 0
        self.bytes_sent = 0
        self._lock = threading.Lock()

    def write(self) -> None:
        fixes = b"".join(
            encode(Telemetry(n, -37260579, 404506308 + n, 702385, 8219, 100))
            for n in range(CHUNK_FRAMES)
        )
        request = encode(ProbePositionRequest(7))
        while not self.stop.is_set():
            write_all(self.fd, fixes)  # blocks while the pty is full: full speed, no faster
            with self._lock:
                write_all(self.fd, request)
                self.asked.append(time.perf_counter())
            self.frames_sent += CHUNK_FRAMES + 1
            self.bytes_sent += len(fixes) + len(request)
        self.written.set()

    def read(self) -> None:
        buffer = b""
        while not self.written.is_set() or len(self.answered) < len(self.asked):
            if not select.select([self.fd], [], [], 1.0)[0]:
                if self.written.is_set():
                    return  # nothing more is coming: a P-S went unanswered
                continue
            buffer += os.read(self.fd, 4096)
            now = time.perf_counter()
            while (start := buffer.find(b"RP")) >= 0 and len(buffer) - start >= 8:
                buffer = buffer[start + 8 :]
                self.answered.append(now)

    def latencies_ms(self) -> list[float]:
        with self._lock:
            pairs = zip(self.asked, self.answered, strict=False)
            return [(answered - asked) * 1000 for asked, answered in pairs]


def main() -> int:
    print(f"== flood: {FLOOD_S:.0f} s of P-T at the pty's full speed, a P-S every 4 kB ==")
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        pty = PtyPair(directory / "ttyAP")
        os.set_blocking(pty.master_fd, True)
        proc = start_daemon(flood_config(directory, pty.path))
        started = time.monotonic()
        try:
            wait_first_answer(pty.master_fd, time.monotonic())
            time.sleep(0.5)
            while select.select([pty.master_fd], [], [], 0.1)[0]:
                os.read(pty.master_fd, 4096)
            flood = Flood(pty.master_fd)
            writer = threading.Thread(target=flood.write, daemon=True)
            reader = threading.Thread(target=flood.read, daemon=True)
            reader.start()
            writer.start()
            time.sleep(WARMUP_S)
            size0, t0 = journal_bytes(directory), time.monotonic()
            sent0 = flood.bytes_sent
            rss_samples: list[float] = []
            while time.monotonic() - t0 < FLOOD_S:
                time.sleep(1.0)
                rss_samples.append(rss_mb(proc.pid))
            elapsed = time.monotonic() - t0
            size1, sent1 = journal_bytes(directory), flood.bytes_sent
            flood.stop.set()
            writer.join(10)
            reader.join(10)
            peak = peak_rss_mb(proc.pid)
            proc.send_signal(signal.SIGTERM)  # a clean stop: the last counts are journaled
            proc.wait(30)
            minutes = (time.monotonic() - started) / 60
            with sqlite3.connect(directory / "journal.db") as db:
                fixes = db.execute("SELECT count(*) FROM fixes").fetchone()[0]
                thinned = db.execute(
                    "SELECT coalesce(sum(json_extract(detail_json, '$.dropped')), 0) FROM events"
                    " WHERE kind = 'telemetry_thinned'"
                ).fetchone()[0]
                db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
            data_kb = (
                (directory / "journal.db").stat().st_size - empty_journal_bytes(directory)
            ) / 1e3
        finally:
            proc.kill()
            proc.wait()
            pty.close()

    ok = True

    def verdict(passed: bool) -> str:
        nonlocal ok
        ok = ok and passed
        return "PASS" if passed else "FAIL"

    growth = (size1 - size0) / 1e6 / elapsed * 60
    rate = (sent1 - sent0) / elapsed
    latencies = flood.latencies_ms()
    print(
        f"flood: {rate / 1e6:.2f} MB/s of valid frames, {flood.frames_sent:,} frames sent; "
        f"{fixes:,} fixes journaled, {thinned:,} counted as thinned"
    )
    print(
        f"resident memory: peak {peak:.1f} MB, last {rss_samples[-1]:.1f} MB (<= 50) "
        f"{verdict(peak <= 50)}"
    )
    print(
        f"journal growth: {growth:.3f} MB/min on disk during the flood (file + WAL) (<= 1) "
        f"{verdict(growth <= 1)}; the data itself: {fixes / minutes:.0f} fixes/min, the file "
        f"+{data_kb:.0f} kB after a final checkpoint over {minutes:.1f} min"
    )
    answered = len(flood.answered) == len(flood.asked)
    print(
        f"P-S under the flood: {len(flood.answered):,}/{len(flood.asked):,} answered "
        f"{verdict(answered)}; latency p50 {percentile(latencies, 50):.2f} ms, "
        f"p99 {percentile(latencies, 99):.2f} ms, max {max(latencies):.2f} ms"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
