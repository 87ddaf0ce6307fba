"""The simulated sonde: a pymodbus RTU server on a pseudo-terminal.

This module owns a stand-in for the real sonde that the daemon reads exactly as
it would read the real one: pymodbus's own RTU server answers the register map
from `water.SondeModel` (the probe's depth from the winch's line out), behind a
pty pair whose symlink the daemon opens like `/dev/ttyUSB0`. Between the
server's pty and the daemon's sits a small byte bridge that

- paces every byte at the configured baud rate (a pty has no baud rate, a
  9600-baud RS-485 line does: 30 registers take ~80 ms), and
- injects faults on demand: `timeout` (the reply is dropped), `crc` (a reply
  byte flipped), `nan` (every value but depth NaN), `exception` (a
  device-failure exception response), and `unplug()`/`replug()` (the adapter
  pulled out: the daemon's port reads EIO and the path disappears).

It runs in its own thread with its own event loop, so it never competes with
the daemon's loop for time, and it never writes to the journal: a reading the
daemon takes from it is journaled as simulated (`sonde.backend = "sim"`).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal, Protocol

import structlog
from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer
from pymodbus.simulator import DataType, SimData, SimDevice

from cc_daemon.config.sonde import DEFAULT_PARAMETERS, SondeParameter
from cc_daemon.drivers.sonde.registers import encode, plan_blocks
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.water import SondeModel

_log = structlog.get_logger("cc_daemon.sim.sonde")

Fault = Literal["timeout", "crc", "nan", "exception"]
FAULTS: tuple[Fault, ...] = ("timeout", "crc", "nan", "exception")
_NAN = float("nan")


class Readings(Protocol):
    """What the sonde senses (`water.SondeModel`, or fixed values in a test)."""

    def read(self, line_out_m: float, t: float) -> dict[str, float]: ...


class SimulatedSonde:
    """A sonde on `path`. `start()` it, read it with any Modbus RTU master, `stop()` it.

    `line_out` gives the winch's line out in metres (the simulated winch's, or a
    scripted cast when run alone). `fault` applies to every request until
    cleared; `fault_rate` injects a random fault into that share of requests.
    """

    def __init__(
        self,
        path: Path,
        *,
        line_out: Callable[[], float],
        parameters: Sequence[SondeParameter] = DEFAULT_PARAMETERS,
        slave_id: int = 80,
        baudrate: int = 9600,
        model: Readings | None = None,
        fault_rate: float = 0.0,
        seed: int = 0,
        only_mapped: bool = False,
    ) -> None:
        """`only_mapped`: registers between the parameters are not mapped, so a read
        across them gets exception 2 (illegal data address), as some sondes do."""
        self.path = Path(path)
        self.only_mapped = only_mapped
        self.line_out = line_out
        self.parameters = tuple(parameters)
        self.slave_id = slave_id
        self.baudrate = baudrate
        self.model: Readings = model or SondeModel(rng=random.Random(seed))
        self.fault: Fault | None = None
        self.fault_rate = fault_rate
        self.requests = 0  # requests that reached the server
        self.faults_injected = 0
        self.last_reply = b""  # the last reply's bytes as the server sent them
        self._rng = random.Random(seed + 1)
        self._pending_fault: Fault | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._tmp = tempfile.TemporaryDirectory(prefix="cc-sonde-")
        self._server_pty = PtyPair(Path(self._tmp.name) / "server")
        self._client_pty = PtyPair(self.path)
        self._started_at = time.monotonic()

    # ------------------------------------------------------------ lifecycle

    def start(self) -> None:
        self._thread = threading.Thread(target=self._main, name="simulated-sonde", daemon=True)
        self._thread.start()
        if not self._ready.wait(10.0) or self._error is not None:
            self.stop()
            raise RuntimeError(f"simulated sonde did not start: {self._error!r}")

    def stop(self) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stop.set)
        if self._thread is not None:
            self._thread.join(10.0)
        self._client_pty.close()
        self._server_pty.close()
        self._tmp.cleanup()

    def __enter__(self) -> SimulatedSonde:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def unplug(self) -> None:
        """Pull the adapter out: the daemon's port fails and the path disappears."""
        self._call(self._unplug)

    def replug(self) -> None:
        """Plug it back in (a new pty behind the same path)."""
        self._call(self._replug)

    @property
    def plugged(self) -> bool:
        return self._client_pty.plugged

    # ------------------------------------------------------------ the thread

    def _call(self, fn: Callable[[], None]) -> None:
        loop = self._loop
        if loop is None:
            fn()
            return
        done = threading.Event()

        def run() -> None:
            try:
                fn()
            finally:
                done.set()

        loop.call_soon_threadsafe(run)
        done.wait(5.0)

    def _main(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # reported to start(); the thread must end quietly
            self._error = exc
            self._ready.set()

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        blocks = plan_blocks(self.parameters, gaps=not self.only_mapped)
        device = SimDevice(
            self.slave_id,
            simdata=[
                SimData(b.address, count=b.count, values=0, datatype=DataType.REGISTERS)
                for b in blocks
            ],
            action=self._action,
        )
        server = ModbusSerialServer(
            device,
            framer=FramerType.RTU,
            port=self._server_pty.slave_name,
            baudrate=self.baudrate,
            trace_packet=self._trace_packet,
        )
        await server.serve_forever(background=True)
        self._watch(self._client_pty.master_fd, self._from_client)
        self._watch(self._server_pty.master_fd, self._from_server)
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            self._unwatch()
            await server.shutdown()  # type: ignore[no-untyped-call]

    def _watch(self, fd: int, handler: Callable[[bytes], None]) -> None:
        assert self._loop is not None

        def readable() -> None:
            try:
                data = os.read(fd, 4096)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                data = b""
            if not data:
                with contextlib.suppress(ValueError, OSError):
                    self._loop.remove_reader(fd) if self._loop else None
                return
            handler(data)

        self._loop.add_reader(fd, readable)

    def _unwatch(self) -> None:
        assert self._loop is not None
        for fd in (self._client_pty.master_fd, self._server_pty.master_fd):
            if fd >= 0:
                with contextlib.suppress(ValueError, OSError):
                    self._loop.remove_reader(fd)

    def _unplug(self) -> None:
        if self._loop is not None and self._client_pty.master_fd >= 0:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(self._client_pty.master_fd)
        self._client_pty.unplug()

    def _replug(self) -> None:
        self._unplug()
        self._client_pty.replug()
        self._watch(self._client_pty.master_fd, self._from_client)

    def _wire_s(self, data: bytes) -> float:
        return len(data) * 10 / self.baudrate  # 8N1: ten bits a byte

    def _from_client(self, data: bytes) -> None:
        # The request arrives once all its bits have crossed the line.
        fd = self._server_pty.master_fd
        assert self._loop is not None
        self._loop.call_later(self._wire_s(data), self._write, fd, data)

    def _from_server(self, data: bytes) -> None:
        self.last_reply = data
        fault, self._pending_fault = self._pending_fault, None
        if fault == "timeout":
            return
        if fault == "crc":
            data = data[:-1] + bytes([data[-1] ^ 0x5A])
        fd = self._client_pty.master_fd
        assert self._loop is not None
        self._loop.call_later(self._wire_s(data), self._write, fd, data)

    def _write(self, fd: int, data: bytes) -> None:
        if fd < 0:
            return
        with contextlib.suppress(OSError):  # unplugged meanwhile: the bytes are lost
            os.write(fd, data)

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        return data

    # ------------------------------------------------------------ the registers

    def _choose_fault(self) -> Fault | None:
        if self.fault is not None:
            return self.fault
        if self.fault_rate > 0 and self._rng.random() < self.fault_rate:
            return self._rng.choice(FAULTS)
        return None

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        current_registers: list[int],
        set_values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        self.requests += 1
        fault = self._choose_fault()
        if fault is not None:
            self.faults_injected += 1
        self._pending_fault = fault if fault in ("timeout", "crc") else None
        if fault == "exception":
            return ExcCodes.DEVICE_FAILURE
        values = self.model.read(self.line_out(), time.monotonic() - self._started_at)
        for p in self.parameters:
            value = values.get(p.name, 0.0)
            if fault == "nan" and p.name != "depth":
                value = _NAN
            offset = p.address - start_address
            if offset >= 0 and offset + p.count <= len(current_registers):
                current_registers[offset : offset + p.count] = encode(p, value)
        return None


def yo_yo(max_m: float = 8.0, speed_m_s: float = 0.25) -> Callable[[], float]:
    """A line out that goes down to `max_m` and back, forever (the sonde run alone)."""
    started = time.monotonic()
    period = 2 * max_m / speed_m_s

    def line_out() -> float:
        phase = (time.monotonic() - started) % period
        return min(phase, period - phase) * speed_m_s

    return line_out
