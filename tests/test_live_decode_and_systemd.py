"""`cc-daemon decode --port` on a real pty, and sd_notify over a real socket."""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cc_daemon.core.protocol import Ack, DepthReport, ProbePositionRequest, encode
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import REPO
from tests.waitkit import DEADLINE_S


def _read_lines(stream: object, count: int, timeout: float) -> list[str]:
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    fd = stream.fileno()  # type: ignore[attr-defined]
    buffer = b""
    while len(lines) < count and time.monotonic() < deadline:
        if select.select([fd], [], [], 0.1)[0]:
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            buffer += chunk
            *done, buffer = buffer.split(b"\n")
            lines += [line.decode() for line in done]
    return lines


@pytest.mark.slow
def test_decode_port_prints_both_directions_until_ctrl_c(tmp_path: Path) -> None:
    with PtyPair(tmp_path / "tty") as pty:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "cc_daemon",
                "decode",
                "--json",
                "--shared",
                "--port",
                str(pty.path),
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=dict(os.environ, PYTHONPATH=str(REPO)),
        )
        try:
            assert proc.stderr is not None and proc.stdout is not None
            assert any("open" in line for line in _read_lines(proc.stderr, 1, DEADLINE_S))
            os.write(pty.master_fd, encode(ProbePositionRequest(72)) + b"\x00")
            os.write(pty.master_fd, bytes.fromhex("50 53 00 48 00 EC") + encode(Ack(72)))
            os.write(pty.master_fd, encode(DepthReport(73, 1500)))
            lines = _read_lines(proc.stdout, 4, DEADLINE_S)
            objs = [json.loads(line) for line in lines]
            assert objs == [
                {"frame": "P-S", "timestamp_s": 72},
                {
                    "error": "bad_checksum",
                    "bytes": "50 53 00 48 00 EC",
                    "detail": objs[1]["detail"],
                },
                {"frame": "R-O", "timestamp_s": 72},
                {"frame": "R-M", "timestamp_s": 73, "depth_mm": 1500},
            ]
            proc.send_signal(signal.SIGINT)
            assert proc.wait(DEADLINE_S) == 1  # errors were seen
            summary = proc.stderr.read().decode()
            assert "3 frames, 1 errors" in summary
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            for stream in (proc.stdout, proc.stderr):
                if stream is not None:
                    stream.close()


def test_notifier_sends_datagrams_to_notify_socket(tmp_path: Path) -> None:
    path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(path))
        notifier = SystemdNotifier(str(path), watchdog=True)
        try:
            notifier.notify("READY=1", "STATUS=answering on /dev/serial0")
            notifier.watchdog()
            assert server.recv(1024) == b"READY=1\nSTATUS=answering on /dev/serial0"
            assert server.recv(1024) == b"WATCHDOG=1"
        finally:
            notifier.close()


def test_notifier_outside_systemd_does_nothing_and_never_raises(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    quiet = SystemdNotifier.from_environment()
    assert not quiet.enabled
    quiet.notify("READY=1")
    broken = SystemdNotifier(str(tmp_path / "nobody-listens.sock"))
    broken.notify("READY=1")  # logged, not raised
    broken.close()


def test_watchdog_only_when_asked_for_this_pid(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NOTIFY_SOCKET", "@cc-daemon-test")
    monkeypatch.setenv("WATCHDOG_USEC", "60000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid() + 1))
    assert not SystemdNotifier.from_environment()._watchdog
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert SystemdNotifier.from_environment()._watchdog
