"""The pty pair and FramePort: a faithful cable, unplug/replug, frames both ways."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import select
import time
from pathlib import Path

import pytest

from cc_daemon.core.protocol import (
    Ack,
    DepthReport,
    ErrorKind,
    Finished,
    ProbePositionRequest,
    Sender,
    StartMeasuring,
    Telemetry,
    encode,
)
from cc_daemon.sim.noise import BitFlipper
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.waitkit import DEADLINE_S, until

EVERY_BYTE = bytes(range(256)) + bytes([0x0D, 0x0A, 0x11, 0x13, 0x03, 0x1A, 0x1C, 0x04, 0x7F])


def _open_slave(path: Path) -> int:
    return os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)


def _read_exactly(fd: int, n: int, timeout: float = DEADLINE_S) -> bytes:
    out = bytearray()
    deadline = time.monotonic() + timeout
    while len(out) < n:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            break
        ready, _, _ = select.select([fd], [], [], remaining)
        if ready:
            out += os.read(fd, n - len(out))
    return bytes(out)


def _assert_hung_up(fd: int) -> None:
    ready, _, _ = select.select([fd], [], [], DEADLINE_S)
    assert ready  # a hang-up wakes the reader
    try:
        outcome: bytes | int | None = os.read(fd, 16)
    except OSError as exc:
        outcome = exc.errno
    assert outcome in (b"", errno.EIO)


def _nothing_before(reader: int, writer: int) -> bool:
    """Whether `reader` had nothing to read (no echo) before a marker `writer` sends
    now: the bytes of one side arrive in order, so the marker proves the moment has
    passed, however slowly the kernel moved them."""
    os.write(writer, b"!")
    return _read_exactly(reader, 1) == b"!"


@pytest.fixture
def pair(tmp_path: Path):
    with PtyPair(tmp_path / "ttyAUTOPILOT") as p:
        yield p


def test_link_is_a_symlink_to_the_slave(pair: PtyPair) -> None:
    assert pair.path.is_symlink()
    assert os.readlink(pair.path) == pair.slave_name
    assert pair.slave_name.startswith("/dev/")
    assert not os.get_blocking(pair.master_fd)


def test_every_byte_value_crosses_master_to_slave_unchanged_without_echo(pair: PtyPair) -> None:
    slave = _open_slave(pair.path)
    try:
        os.write(pair.master_fd, EVERY_BYTE)
        assert _read_exactly(slave, len(EVERY_BYTE)) == EVERY_BYTE
        assert _nothing_before(pair.master_fd, slave)  # no echo back to the autopilot
    finally:
        os.close(slave)


def test_every_byte_value_crosses_slave_to_master_unchanged(pair: PtyPair) -> None:
    slave = _open_slave(pair.path)
    try:
        os.write(slave, EVERY_BYTE)
        assert _read_exactly(pair.master_fd, len(EVERY_BYTE)) == EVERY_BYTE
        assert _nothing_before(slave, pair.master_fd)
    finally:
        os.close(slave)


def test_reader_on_the_slave_sees_a_hangup_after_unplug(pair: PtyPair) -> None:
    slave = _open_slave(pair.path)
    try:
        pair.unplug()
        assert not pair.path.exists()
        assert not pair.path.is_symlink()
        assert pair.master_fd == -1
        _assert_hung_up(slave)
        with pytest.raises(FileNotFoundError):
            _open_slave(pair.path)
    finally:
        os.close(slave)


def test_replug_gives_a_working_pair_at_the_same_path(pair: PtyPair) -> None:
    pair.unplug()
    pair.unplug()  # twice is harmless
    pair.replug()
    assert pair.plugged
    assert pair.path.is_symlink()
    assert os.readlink(pair.path) == pair.slave_name
    assert pair.master_fd >= 0
    slave = _open_slave(pair.path)
    try:
        frame = encode(ProbePositionRequest(72))
        os.write(pair.master_fd, frame)
        assert _read_exactly(slave, len(frame)) == frame
        os.write(slave, b"R")
        assert _read_exactly(pair.master_fd, 1) == b"R"
    finally:
        os.close(slave)


def test_replug_while_plugged_replaces_the_pair(pair: PtyPair) -> None:
    first = pair.slave_name
    slave = _open_slave(pair.path)
    try:
        pair.replug()
        assert os.readlink(pair.path) == pair.slave_name
        assert pair.slave_name != first
        _assert_hung_up(slave)  # the old cable is gone
    finally:
        os.close(slave)


def test_replaces_a_stale_link_and_close_is_idempotent(tmp_path: Path) -> None:
    link = tmp_path / "tty"
    link.symlink_to("/nonexistent")
    pair = PtyPair(link)
    assert os.readlink(link) == pair.slave_name
    pair.close()
    pair.close()
    assert not link.is_symlink()
    assert "unplugged" in repr(pair)


def test_master_survives_the_daemon_closing_the_port(pair: PtyPair) -> None:
    # The daemon closes and reopens the port when it reconnects; the
    # autopilot's end must not see that as a hang-up.
    slave = _open_slave(pair.path)
    os.close(slave)
    # A last close would hang the master up there and then (no waiting: the kernel
    # marks it in the close itself).
    assert not select.select([pair.master_fd], [], [], 0)[0]
    os.write(pair.master_fd, b"P")


async def test_frameport_round_trip_between_the_two_ends(pair: PtyPair) -> None:
    slave = _open_slave(pair.path)
    autopilot = await FramePort.over_fd(pair.master_fd)
    daemon_side = await FramePort.over_fd(slave, listen=Sender.AUTOPILOT)
    try:
        m = StartMeasuring(72, -37260579, 404506308, 702385, 8219, 100)
        await autopilot.send(m)
        await autopilot.send(ProbePositionRequest(73))
        got = [await daemon_side.receive(DEADLINE_S) for _ in range(2)]
        assert [r.message for r in got if r] == [m, ProbePositionRequest(73)]
        assert got[0] is not None
        assert got[0].raw == encode(m)

        before = time.monotonic()
        await daemon_side.send(Ack(72))
        await daemon_side.send(DepthReport(73, 15820))
        await daemon_side.send(encode(Finished(74, 0)))  # raw bytes go as they are
        frames = [await autopilot.receive(DEADLINE_S) for _ in range(3)]
        assert [r.message for r in frames if r] == [
            Ack(72),
            DepthReport(73, 15820),
            Finished(74, 0),
        ]
        assert all(r is not None and before <= r.time <= time.monotonic() for r in frames)
        assert [s.frame for s in autopilot.sent] == [m, ProbePositionRequest(73)]
        assert (autopilot.frames_in, autopilot.frames_out) == (3, 2)
        assert await autopilot.receive(0.05) is None  # nothing more: a timeout, not a hang
    finally:
        await autopilot.close()
        await daemon_side.close()
        os.close(slave)


async def test_frameport_reports_corrupt_frames_and_keeps_going(pair: PtyPair) -> None:
    slave = _open_slave(pair.path)
    autopilot = await FramePort.over_fd(pair.master_fd)
    try:
        bad = bytearray(encode(DepthReport(72, 15820)))
        bad[-1] ^= 0x01
        os.write(slave, b"\x00garbage" + bytes(bad) + encode(Finished(73, 0)))
        got = await autopilot.receive(DEADLINE_S)
        assert got is not None
        assert got.message == Finished(73, 0)
        assert [e.kind for e in autopilot.errors] == [ErrorKind.BAD_CHECKSUM]
    finally:
        await autopilot.close()
        os.close(slave)


async def test_corrupt_frames_are_timed_no_earlier_than_the_flips_that_spoilt_them(
    pair: PtyPair,
) -> None:
    flipper = BitFlipper(1.0, seed=1)  # a bit in bytes 0, 26, 52...
    slave = _open_slave(pair.path)
    autopilot = await FramePort.over_fd(pair.master_fd, rx_filter=flipper)
    try:
        before = time.monotonic()
        # Line noise in bytes 0 and 52, the R-M's type byte at 26: it is spoilt.
        stream = bytes(25) + encode(DepthReport(72, 15820)) + bytes(20) + encode(Finished(73, 0))
        os.write(slave, stream)
        got = await autopilot.receive(DEADLINE_S)
        assert got is not None
        assert got.message == Finished(73, 0)
        assert flipper.bits_flipped == 3
        assert len(autopilot.errors) == len(autopilot.error_times) == 1
        assert before <= flipper.flip_times[1] <= autopilot.error_times[0] <= got.time
    finally:
        await autopilot.close()
        os.close(slave)


async def test_frameport_filters_see_every_byte(pair: PtyPair) -> None:
    def flip_last(data: bytes) -> bytes:
        return data[:-1] + bytes([data[-1] ^ 0x80])

    slave = _open_slave(pair.path)
    autopilot = await FramePort.over_fd(pair.master_fd, tx_filter=flip_last)
    daemon_side = await FramePort.over_fd(slave, listen=Sender.AUTOPILOT)
    try:
        t = Telemetry(1, 0, 0, 0, 0, 0)
        await autopilot.send(t)
        await until(lambda: daemon_side.errors, "the spoilt frame found")
        assert await daemon_side.receive(0) is None  # the frame, once read whole, was spoilt
        assert len(daemon_side.errors) == 1
        assert autopilot.sent[0].frame == t
        assert autopilot.sent[0].wire != encode(t)
    finally:
        await autopilot.close()
        await daemon_side.close()
        os.close(slave)


async def test_frameport_sees_the_hangup_and_a_new_port_works_after_replug(pair: PtyPair) -> None:
    slave = _open_slave(pair.path)
    daemon_side = await FramePort.over_fd(slave, listen=Sender.AUTOPILOT)
    autopilot = await FramePort.over_fd(pair.master_fd)
    try:
        autopilot.detach()  # the autopilot stops reading before the cable is pulled
        pair.unplug()
        assert await daemon_side.receive(DEADLINE_S) is None
        assert daemon_side.hung_up
        with pytest.raises(ConnectionError):
            await autopilot.send(Telemetry(1, 0, 0, 0, 0, 0))
    finally:
        await daemon_side.close()
        os.close(slave)

    pair.replug()
    slave = _open_slave(pair.path)
    daemon_side = await FramePort.over_fd(slave, listen=Sender.AUTOPILOT)
    autopilot = await FramePort.over_fd(pair.master_fd)
    try:
        await autopilot.send(ProbePositionRequest(9))
        got = await daemon_side.receive(DEADLINE_S)
        assert got is not None
        assert got.message == ProbePositionRequest(9)
    finally:
        await autopilot.close()
        await daemon_side.close()
        os.close(slave)


async def test_send_waits_while_nobody_reads_then_completes(pair: PtyPair) -> None:
    # Fill the pty's queue (nobody reads the slave), then drain it: `send`
    # must neither lose bytes nor raise BlockingIOError.
    autopilot = await FramePort.over_fd(pair.master_fd)
    slave = _open_slave(pair.path)
    try:
        frame = encode(Telemetry(1, 2, 3, 4, 5, 6))
        count = 2000  # 50 KB: far more than a pty buffers
        sender = asyncio.create_task(_send_many(autopilot, frame, count))
        received = bytearray()
        deadline = time.monotonic() + DEADLINE_S
        while len(received) < count * len(frame) and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
            with contextlib.suppress(BlockingIOError):
                received += os.read(slave, 65536)
        await asyncio.wait_for(sender, DEADLINE_S)
        assert bytes(received) == frame * count
    finally:
        await autopilot.close()
        os.close(slave)


async def _send_many(port: FramePort, frame: bytes, count: int) -> None:
    for _ in range(count):
        await port.send(frame)


async def test_frameport_over_a_serial_port(pair: PtyPair) -> None:
    # `simulate-autopilot --port` opens a real serial device; the pty slave is one.
    serial_side = await FramePort.over_serial(str(pair.path), 9600, listen=Sender.AUTOPILOT)
    autopilot = await FramePort.over_fd(pair.master_fd)
    try:
        await autopilot.send(ProbePositionRequest(5))
        got = await serial_side.receive(DEADLINE_S)
        assert got is not None
        assert got.message == ProbePositionRequest(5)
        await serial_side.send(DepthReport(5, 1234))
        back = await autopilot.receive(DEADLINE_S)
        assert back is not None
        assert back.message == DepthReport(5, 1234)
    finally:
        await autopilot.close()
        await serial_side.close()
        await serial_side.close()
    assert await serial_side.receive(0.5) is None


async def test_serial_frameport_sees_the_cable_pulled(pair: PtyPair) -> None:
    serial_side = await FramePort.over_serial(str(pair.path), 9600, listen=Sender.AUTOPILOT)
    try:
        pair.unplug()
        assert await serial_side.receive(DEADLINE_S) is None
        assert serial_side.hung_up
        with pytest.raises(ConnectionError):
            await serial_side.send(Ack(1))
    finally:
        await serial_side.close()
