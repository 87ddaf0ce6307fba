"""A serial port as an asyncio transport: a plain reader on its file descriptor.

pyserial opens the port and sets it up (baud rate, framing, raw mode, the
exclusive lock); from then on the loop watches the descriptor itself
(`loop.add_reader`), reads with one `os.read` and writes with one `os.write`.
pyserial-asyncio's transport did the same through pyserial's `read`/`write`,
which add a `select` per read and register the descriptor for writing around
each write. Measured (`benchmarks/transport.py`, a P-S answered on a pty): 32 µs
of CPU per request against 89 µs through pyserial-asyncio and 58 µs through
pyserial-asyncio-fast, and the lowest R-P p50 and p99 of the three
(docs/performance.md).

This module owns only moving bytes and saying when the port is gone (an error,
or end of file: the USB adapter unplugged); `link.SerialLink` decides what to
do then. It never parses, retries or logs.
"""

from __future__ import annotations

import asyncio
import os
from typing import Any

import serial

READ_SIZE = 4096


class SerialGone(serial.SerialException):  # type: ignore[misc]  # pyserial has no types
    """The port reported data but had none: the device went away."""


class FdSerialTransport(asyncio.Transport):
    def __init__(
        self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol, port: serial.Serial
    ) -> None:
        super().__init__()
        self._loop = loop
        self._protocol = protocol
        self._port = port
        self._fd: int = port.fileno()
        self._pending = bytearray()  # what a full kernel buffer refused, in order
        self._closing = False
        self._closed = False
        os.set_blocking(self._fd, False)
        loop.add_reader(self._fd, self._read_ready)
        loop.call_soon(protocol.connection_made, self)

    # -------------------------------------------------------------- reading

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # EIO, ENXIO: the adapter is gone
            self._fail(exc)
            return
        if not data:
            self._fail(SerialGone("device reports readiness to read but returned no data"))
            return
        self._protocol.data_received(data)

    # -------------------------------------------------------------- writing

    def write(self, data: bytes | bytearray | memoryview) -> None:
        if self._closing or not data:
            return
        if self._pending:  # behind earlier bytes: keep the order
            self._pending += data
            return
        try:
            sent = os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError as exc:
            self._fail(exc)
            return
        if sent < len(data):
            self._pending += memoryview(data)[sent:]
            self._loop.add_writer(self._fd, self._write_ready)

    def _write_ready(self) -> None:
        try:
            sent = os.write(self._fd, self._pending)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._fail(exc)
            return
        del self._pending[:sent]
        if not self._pending:
            self._loop.remove_writer(self._fd)
            if self._closing:
                self._finish(None)

    def get_write_buffer_size(self) -> int:
        return len(self._pending)

    # -------------------------------------------------------------- closing

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        """Stop reading; close once what is pending is written."""
        if self._closing:
            return
        self._closing = True
        self._loop.remove_reader(self._fd)
        if not self._pending:
            self._finish(None)

    def abort(self) -> None:
        self._fail(None)

    def _fail(self, exc: BaseException | None) -> None:
        self._closing = True
        self._pending.clear()
        self._loop.remove_reader(self._fd)
        self._loop.remove_writer(self._fd)
        self._finish(exc)

    def _finish(self, exc: BaseException | None) -> None:
        if self._closed:
            return
        self._closed = True
        self._loop.call_soon(self._lost, exc)

    def _lost(self, exc: BaseException | None) -> None:
        try:
            self._protocol.connection_lost(exc)  # type: ignore[arg-type]
        finally:
            self._port.close()

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return self._port if name == "serial" else default


async def create_serial_connection(
    loop: asyncio.AbstractEventLoop,
    protocol_factory: Any,
    url: str,
    **kwargs: Any,
) -> tuple[FdSerialTransport, asyncio.Protocol]:
    """Open `url` with pyserial (`kwargs`: baudrate, parity, exclusive...) and serve
    it to the protocol `protocol_factory` makes, as pyserial-asyncio's function does."""
    port = serial.serial_for_url(url, **kwargs)
    protocol = protocol_factory()
    try:
        transport = FdSerialTransport(loop, protocol, port)
    except BaseException:
        port.close()
        raise
    return transport, protocol
