"""End-to-end kit: the daemon as a real subprocess on one end of a pty pair.

The test is the autopilot: it holds the pty master through the simulator's
`FramePort` and speaks real frames. The daemon gets the symlink to the slave
as its serial port, a TOML config file, its own journal file, and logs JSON
lines to a file the test can read.

A test waits on the event it checks, never on a sleep (`tests/waitkit.py` polls a
condition): `expect`, `next_frame` and `collect_until` take frames until the one
wanted, each with a deadline (`WAIT_S`) that only a broken daemon reaches and that
costs nothing when the event comes. That something does NOT happen is shown by an
event that proves the moment has passed (`frames_before_reply`: the answer to a
later frame has arrived, so an answer to an earlier one would have come first).
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from cc_daemon.core.protocol import Message, ProbePosition, ProbePositionRequest, StartMeasuring
from cc_daemon.sim.port import FramePort, Received
from cc_daemon.sim.pty import PtyPair

REPO = Path(__file__).resolve().parent.parent

# How long a test waits for something that should happen: far beyond what any load
# makes of it (a wait returns as soon as the event comes, so it costs nothing).
WAIT_S = 30.0
# How long a daemon process may take to start (to answer, or to exit on a bad
# setting): its imports alone took 10 to 25 s on 2 cores at a load average of 25.
START_S = 60.0


async def next_frame(
    port: FramePort, kind: type[Message] | None = None, timeout: float = WAIT_S
) -> Received:
    """The next frame (of `kind`, when given: others are skipped, still recorded)."""
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        got = await port.receive(left)
        if got is not None and (kind is None or type(got.message) is kind):
            return got
    raise AssertionError(
        f"no {'frame' if kind is None else kind.__name__} within {timeout:g} s;"
        f" received: {[r.message for r in port.received[-10:]]}"
    )


async def collect_until(
    port: FramePort, last: Callable[[Message], bool], timeout: float = WAIT_S
) -> list[Received]:
    """Every frame up to and including the first for which `last(message)` holds."""
    out: list[Received] = []
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        got = await port.receive(left)
        if got is not None:
            out.append(got)
            if last(got.message):
                return out
    raise AssertionError(f"not within {timeout:g} s; got {[r.message for r in out]}")


def nth(kind: type[Message], n: int) -> Callable[[Message], bool]:
    """For `collect_until`: true at the `n`th frame of `kind`."""
    seen = 0

    def counted(message: Message) -> bool:
        nonlocal seen
        seen += type(message) is kind
        return seen >= n

    return counted


async def frames_before_reply(
    port: FramePort, timestamp: int = 40_000, timeout: float = WAIT_S
) -> list[Message]:
    """What the daemon sends before its answer to a P-S sent now (the answer itself
    is not included). The daemon answers frames in the order they arrive, so anything
    it was going to say to what came before the P-S has arrived by then: an empty
    list proves it said nothing, however slow the machine."""
    await port.send(ProbePositionRequest(timestamp))
    frames = await collect_until(
        port, lambda m: isinstance(m, ProbePosition) and m.timestamp_s == timestamp, timeout
    )
    return [r.message for r in frames[:-1]]


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

    async def start_and_connect(self, timeout: float = START_S) -> FramePort:
        self.start()
        port = await self.connect()
        await self.wait_answering(timeout)
        return port

    async def wait_answering(self, timeout: float = START_S) -> None:
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
        self, kind: type[Message], timeout: float = WAIT_S, *, fail: bool = True
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
        """Every frame for `seconds`: only where the time is the point (a scenario's
        length); to wait for a frame, use `expect` or `collect_until`."""
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

    async def wait_exit(self, timeout: float = START_S) -> int:
        assert self.proc is not None
        deadline = time.monotonic() + timeout
        while self.proc.poll() is None:
            if time.monotonic() > deadline:
                raise AssertionError(f"daemon still running after {timeout} s:\n{self.log_text()}")
            await asyncio.sleep(0.05)
        return self.proc.returncode

    def log_text(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    async def logged(self, event: str, timeout: float = WAIT_S) -> dict[str, Any]:
        """The first log event whose text contains `event`, once the daemon has written it."""

        from tests.waitkit import until  # (waitkit imports this module)

        def find() -> dict[str, Any] | None:
            return next((e for e in self.log_events() if event in str(e.get("event"))), None)

        found = await until(find, f"log event {event!r}", timeout)
        assert found is not None
        return found

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
