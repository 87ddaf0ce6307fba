"""End-to-end kit: the daemon as a real subprocess on one end of a pty pair.

The test is the autopilot: it holds the pty master through the simulator's
`FramePort` and speaks real frames. The daemon gets the symlink to the slave
as its serial port, a TOML config file, its own journal file, and logs JSON
lines to a file the test can read.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from cc_daemon.core.protocol import Message, ProbePosition, ProbePositionRequest, StartMeasuring
from cc_daemon.sim.port import FramePort, Received
from cc_daemon.sim.pty import PtyPair

REPO = Path(__file__).resolve().parent.parent

# Fast casts: 3 m at 1 m/s, 1 s at the bottom -> R-F about 7 s after R-O. The
# simulated winch outside --simulate must be asked for by name (cc_daemon.daemon.simgate).
FAST_CAST: dict[str, Any] = {
    "winch": {
        "backend": "sim",
        "max_line_m": 20.0,
        "sim": {"speed_m_s": 1.0, "allow_outside_simulation": True},
    },
    "cast": {"target_depth_m": 3.0, "bottom_dwell_s": 1.0, "max_duration_s": 60.0},
}


def toml_text(config: Mapping[str, Any], prefix: str = "") -> str:
    """A small TOML writer for nested tables of scalars (enough for our config)."""
    scalars = {k: v for k, v in config.items() if not isinstance(v, Mapping)}
    tables = {k: v for k, v in config.items() if isinstance(v, Mapping)}
    lines = [f"[{prefix}]"] if prefix and scalars else []
    for key, value in scalars.items():
        lines.append(
            f"{key} = {json.dumps(value) if not isinstance(value, bool) else str(value).lower()}"
        )
    text = "\n".join(lines) + ("\n" if lines else "")
    for key, value in tables.items():
        text += toml_text(value, f"{prefix}.{key}" if prefix else key)
    return text


def merge(base: Mapping[str, Any], extra: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def station(
    sonar_mm: int = 30_000, confidence: int = 100, timestamp: int = 100, lat_e7: int = 404506308
) -> StartMeasuring:
    return StartMeasuring(timestamp, -37260579, lat_e7, 702385, sonar_mm, confidence)


class DaemonProcess:
    def __init__(self, tmp_path: Path, config: Mapping[str, Any] | None = None) -> None:
        self.tmp = tmp_path
        self.pty = PtyPair(tmp_path / "ttyAP")
        self.db = tmp_path / "journal.db"
        self.log_path = tmp_path / "daemon.log"
        base = {"serial": {"port": str(self.pty.path)}, "store": {"path": str(self.db)}}
        self.config = merge(merge(base, FAST_CAST), config or {})
        self.config_path = tmp_path / "cc-daemon.toml"
        self.config_path.write_text(toml_text(self.config))
        self.proc: subprocess.Popen[bytes] | None = None
        self.port: FramePort | None = None

    def start(
        self,
        *args: str,
        prefix: Sequence[str] = (),
        env: Mapping[str, str] | None = None,
    ) -> None:
        """Start the daemon; `prefix` wraps the command (a sandbox), `env` adds variables."""
        environ = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
        environ["PYTHONPATH"] = str(REPO)
        environ.update(env or {})
        with self.log_path.open("wb") as log:
            self.proc = subprocess.Popen(
                [
                    *prefix,
                    sys.executable,
                    "-m",
                    "cc_daemon",
                    "--config",
                    str(self.config_path),
                    "--log-format",
                    "json",
                    "--log-level",
                    "debug",
                    *args,
                ],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                env=environ,
                cwd=self.tmp,
            )

    async def connect(self) -> FramePort:
        self.port = await FramePort.over_fd(self.pty.master_fd)
        return self.port

    async def start_and_connect(self, timeout: float = 15.0) -> FramePort:
        self.start()
        port = await self.connect()
        await self.wait_answering(timeout)
        return port

    async def wait_answering(self, timeout: float = 15.0) -> None:
        """Ask S until the daemon answers R-P."""
        assert self.port is not None
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.check_alive()
            await self.port.send(ProbePositionRequest(1))
            reply = await self.expect(ProbePosition, 0.3, fail=False)
            if reply is not None:
                return
        raise AssertionError(f"daemon did not answer within {timeout} s:\n{self.log_text()}")

    async def expect(
        self, kind: type[Message], timeout: float, *, fail: bool = True
    ) -> Received | None:
        """The next frame of `kind` (other frames are skipped, still recorded)."""
        assert self.port is not None
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            got = await self.port.receive(left)
            if got is not None and type(got.message) is kind:
                return got
        if fail:
            raise AssertionError(
                f"no {kind.__name__} within {timeout} s:\n{self.log_text()[-3000:]}"
            )
        return None

    async def collect(self, seconds: float) -> list[Received]:
        assert self.port is not None
        out: list[Received] = []
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            got = await self.port.receive(left)
            if got is not None:
                out.append(got)
        return out

    def check_alive(self) -> None:
        assert self.proc is not None
        if self.proc.poll() is not None:
            raise AssertionError(f"daemon exited with {self.proc.returncode}:\n{self.log_text()}")

    def send_signal(self, signum: int = signal.SIGTERM) -> None:
        assert self.proc is not None
        self.proc.send_signal(signum)

    async def wait_exit(self, timeout: float = 20.0) -> int:
        assert self.proc is not None
        deadline = time.monotonic() + timeout
        while self.proc.poll() is None:
            if time.monotonic() > deadline:
                raise AssertionError(f"daemon still running after {timeout} s:\n{self.log_text()}")
            await asyncio.sleep(0.05)
        return self.proc.returncode

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def log_events(self) -> list[dict[str, Any]]:
        events = []
        for line in self.log_text().splitlines():
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return events

    async def close(self) -> None:
        if self.port is not None:
            await self.port.close()
            self.port = None
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(5)
        self.pty.close()
