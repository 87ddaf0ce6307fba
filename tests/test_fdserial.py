"""The link's transport (`drivers/fdserial.py`) on a real pty: a write the kernel
cannot take at once still arrives whole and in order, and an unplug is reported."""

from __future__ import annotations

import asyncio
import os
import select
from pathlib import Path

from cc_daemon.drivers import fdserial
from cc_daemon.sim.pty import PtyPair
from tests.waitkit import DEADLINE_S, until


class Recorder(asyncio.Protocol):
    def __init__(self) -> None:
        self.data = bytearray()
        self.lost: asyncio.Future[BaseException | None] = asyncio.get_running_loop().create_future()

    def data_received(self, data: bytes) -> None:
        self.data += data

    def connection_lost(self, exc: BaseException | None) -> None:
        self.lost.set_result(exc)


async def _read_master(fd: int, size: int, timeout: float = DEADLINE_S) -> bytes:
    out = bytearray()
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while len(out) < size and loop.time() < deadline:
        if select.select([fd], [], [], 0)[0]:
            out += os.read(fd, 65536)
        else:
            await asyncio.sleep(0.001)  # the loop writes the rest meanwhile
    return bytes(out)


async def test_a_write_bigger_than_the_kernel_buffer_arrives_whole_and_in_order(
    tmp_path: Path,
) -> None:
    pty = PtyPair(tmp_path / "tty")
    try:
        loop = asyncio.get_running_loop()
        transport, protocol = await fdserial.create_serial_connection(
            loop, Recorder, str(pty.path), baudrate=9600
        )
        big = bytes(range(256)) * 256  # 64 KiB: far more than a pty holds
        transport.write(big)
        transport.write(b"after")  # queued behind the rest, never before it
        assert transport.get_write_buffer_size() > 0
        got = await _read_master(pty.master_fd, len(big) + 5)
        assert got == big + b"after"
        assert transport.get_write_buffer_size() == 0
        os.write(pty.master_fd, b"PS\x00H\x00\xeb")
        await until(lambda: len(protocol.data) >= 6)  # type: ignore[attr-defined]
        assert bytes(protocol.data) == b"PS\x00H\x00\xeb"  # type: ignore[attr-defined]
        transport.close()
        lost = await asyncio.wait_for(protocol.lost, DEADLINE_S)  # type: ignore[attr-defined]
        assert lost is None
    finally:
        pty.close()


async def test_an_unplug_ends_the_connection_with_the_error(tmp_path: Path) -> None:
    pty = PtyPair(tmp_path / "tty")
    try:
        loop = asyncio.get_running_loop()
        transport, protocol = await fdserial.create_serial_connection(
            loop, Recorder, str(pty.path), baudrate=9600
        )
        pty.unplug()
        exc = await asyncio.wait_for(protocol.lost, DEADLINE_S)  # type: ignore[attr-defined]
        assert isinstance(exc, OSError | fdserial.SerialGone)
        assert transport.is_closing()
        transport.write(b"RO\x00H\x00\xe9")  # after the loss: dropped, never raises
    finally:
        pty.close()
