"""Frame-level asyncio I/O for one end of the autopilot link.

This module owns moving whole frames across a byte stream: encode and write
each frame in one piece, read whatever arrives, feed it to the codec's
`Parser`, and keep a time-stamped record of everything sent, received and
found corrupt. It runs over a non-blocking file descriptor (the master end of
a `PtyPair`) or over a real serial port (pyserial-asyncio).

It never decides what to send or when (that is the caller: the simulated
autopilot, a test), never closes a descriptor it was lent (`over_fd`), and
never raises because of bad bytes from the peer: they become `errors`.

Times are `time.monotonic()` seconds, the event loop's clock. A received
frame's time (and a corrupt frame's, in `error_times`) is taken when the read
that completed it returned, after `rx_filter` saw the bytes.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import serial_asyncio

from cc_daemon.core.protocol import CorruptFrame, Message, Parser, Sender, encode

ByteFilter = Callable[[bytes], bytes]

_READ_SIZE = 4096


class Received(NamedTuple):
    """One decoded frame from the peer."""

    time: float
    message: Message
    raw: bytes  # the frame's bytes (re-encoded: the wire form of a frame is unique)


class Sent(NamedTuple):
    """One frame (or raw bytes) we wrote."""

    time: float
    frame: Message | bytes  # what the caller asked to send
    wire: bytes  # what went on the wire, after any `tx_filter`


class FramePort:
    """Frames in and out over one end of the link. Build with `over_fd` or `over_serial`.

    `listen` says whose frames to decode: the daemon's (`Sender.CC`, the
    autopilot side; the default) or the autopilot's (`Sender.AUTOPILOT`, a
    test's stand-in daemon). `tx_filter` and `rx_filter` see every byte
    written and read (the simulator's bit-flipper uses them).
    """

    def __init__(
        self,
        *,
        listen: Sender = Sender.CC,
        tx_filter: ByteFilter | None = None,
        rx_filter: ByteFilter | None = None,
    ) -> None:
        self._loop = asyncio.get_running_loop()
        self.parser = Parser(listen)
        self.tx_filter = tx_filter
        self.rx_filter = rx_filter
        self.sent: list[Sent] = []
        self.received: list[Received] = []
        self.errors: list[CorruptFrame] = []
        self.error_times: list[float] = []  # when each of `errors` was found, in step with it
        self.read_times: list[float] = []  # every read's time, which its frames and errors carry
        self.bytes_in = 0
        self.bytes_out = 0
        self.hung_up = False  # the peer hung up (EIO / end of file): nothing more will arrive
        self.read_error: OSError | None = None  # what ended the reading, if it was an error
        self._queue: asyncio.Queue[Received | None] = asyncio.Queue()
        self._fd = -1
        self._reading = False
        self._pending = bytearray()  # written bytes the fd did not take yet
        self._drained: asyncio.Event = asyncio.Event()
        self._drained.set()
        self._transport: Any = None  # pyserial-asyncio's SerialTransport (untyped)
        self._lost: asyncio.Future[None] | None = None

    # ------------------------------------------------------------ construction

    @classmethod
    async def over_fd(
        cls,
        fd: int,
        *,
        listen: Sender = Sender.CC,
        tx_filter: ByteFilter | None = None,
        rx_filter: ByteFilter | None = None,
    ) -> FramePort:
        """A port over a descriptor we do not own (made non-blocking; never closed here)."""
        port = cls(listen=listen, tx_filter=tx_filter, rx_filter=rx_filter)
        os.set_blocking(fd, False)
        port._fd = fd
        port._loop.add_reader(fd, port._read_ready)
        port._reading = True
        return port

    @classmethod
    async def over_serial(
        cls,
        path: str,
        baudrate: int,
        *,
        listen: Sender = Sender.CC,
        tx_filter: ByteFilter | None = None,
        rx_filter: ByteFilter | None = None,
    ) -> FramePort:
        """A port over a serial device, 8N1 without flow control, as the link requires."""
        port = cls(listen=listen, tx_filter=tx_filter, rx_filter=rx_filter)
        port._lost = port._loop.create_future()
        transport, _ = await serial_asyncio.create_serial_connection(
            port._loop, lambda: _SerialProtocol(port), path, baudrate=baudrate
        )
        port._transport = transport  # connection_made comes later, on the loop
        port._reading = True
        return port

    # ------------------------------------------------------------ sending

    async def send(self, frame: Message | bytes) -> None:
        """Write one frame (a message, encoded here, or raw bytes as given)."""
        data = frame if isinstance(frame, bytes) else encode(frame)
        wire = self.tx_filter(data) if self.tx_filter is not None else data
        self.sent.append(Sent(time.monotonic(), frame, wire))
        self.bytes_out += len(wire)
        if self._transport is not None:
            self._transport.write(wire)
            return
        if self._fd < 0:
            raise ConnectionError("the port is detached")
        self._write(wire)
        if self._pending:
            await self._drained.wait()

    def _write(self, data: bytes) -> None:
        if self._pending:
            self._pending += data
            return
        try:
            written = os.write(self._fd, data)
        except BlockingIOError:
            written = 0
        if written < len(data):
            # The pty's queue is full (nobody is reading the other end):
            # keep the rest and finish when the descriptor is writable.
            self._pending += data[written:]
            self._drained.clear()
            self._loop.add_writer(self._fd, self._write_ready)

    def _write_ready(self) -> None:
        try:
            written = os.write(self._fd, self._pending)
        except BlockingIOError:
            return
        except OSError:
            self._drop_pending()
            return
        del self._pending[:written]
        if not self._pending:
            self._loop.remove_writer(self._fd)
            self._drained.set()

    def _drop_pending(self) -> None:
        if self._fd >= 0:
            self._loop.remove_writer(self._fd)
        self._pending.clear()
        self._drained.set()

    # ------------------------------------------------------------ receiving

    async def receive(self, timeout: float) -> Received | None:
        """The next frame from the peer, or None after `timeout` seconds or once it hung up."""
        if self._queue.empty() and (self.hung_up or not self._reading):
            return None
        try:
            async with asyncio.timeout(timeout):
                return await self._queue.get()
        except TimeoutError:
            return None

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, _READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:  # EIO is the hang-up; anything else ends the line just as well
            self.read_error = exc
            data = b""
        if not data:
            self._hang_up()
            return
        self._data_received(data)

    def _data_received(self, data: bytes) -> None:
        if self.rx_filter is not None:
            data = self.rx_filter(data)
        now = time.monotonic()  # after the filter: what it did to these bytes is not later
        self.read_times.append(now)
        self.bytes_in += len(data)
        for event in self.parser.events(data):
            if isinstance(event, CorruptFrame):
                self.errors.append(event)
                self.error_times.append(now)
                continue
            received = Received(now, event, encode(event))
            self.received.append(received)
            self._queue.put_nowait(received)

    def _hang_up(self) -> None:
        self.hung_up = True
        self._stop_reading()
        self._queue.put_nowait(None)  # wake a waiting `receive`

    # ------------------------------------------------------------ teardown

    def _stop_reading(self) -> None:
        if self._reading and self._fd >= 0:
            self._loop.remove_reader(self._fd)
        self._reading = False

    def detach(self) -> None:
        """Stop reading and writing the descriptor, leaving it open for its owner."""
        self._stop_reading()
        self._drop_pending()
        self._fd = -1
        self._queue.put_nowait(None)

    async def close(self) -> None:
        """Detach (descriptor ports) or close the serial port. Safe to call twice."""
        if self._transport is not None:
            transport, self._transport = self._transport, None
            self._reading = False
            transport.close()
            if self._lost is not None:
                await self._lost
            return
        self.detach()

    @property
    def frames_in(self) -> int:
        return len(self.received)

    @property
    def frames_out(self) -> int:
        return len(self.sent)


class _SerialProtocol(asyncio.Protocol):
    """Hands pyserial-asyncio's callbacks to a `FramePort`."""

    def __init__(self, port: FramePort) -> None:
        self._port = port

    def data_received(self, data: bytes) -> None:
        self._port._data_received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        port = self._port
        if port._transport is not None:  # lost, not closed by us
            port._transport = None
            port._hang_up()
        else:
            port._queue.put_nowait(None)
        if port._lost is not None and not port._lost.done():
            port._lost.set_result(None)
        del exc  # the hang-up is the information; the caller decides what to do
