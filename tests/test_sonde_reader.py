"""The sonde reader against pymodbus's own RTU server, over real pseudo-terminals."""

from __future__ import annotations

import asyncio
import os
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from cc_daemon.config.sonde import SondeSettings
from cc_daemon.drivers.sonde.reader import (
    CRC,
    DISCONNECTED,
    EXCEPTION,
    OK,
    PARTIAL,
    TIMEOUT,
    SondeReader,
)
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.sonde import SimulatedSonde
from tests.waitkit import until

# Values whose float bit patterns are easy to recognise on the wire.
KNOWN = {
    "depth": 1.0,  # 0x3F800000
    "temperature": -2.0,  # 0xC0000000
    "ph": 7.0,  # 0x40E00000
    "do_saturation": 100.0,  # 0x42C80000
    "do_concentration": 8.5,  # 0x41080000
    "blue": 0.5,  # 0x3F000000
    "chlorophyll": 25.0,  # 0x41C80000
}


class Fixed:
    def __init__(self) -> None:
        self.values = dict(KNOWN)

    def read(self, line_out_m: float, t: float) -> dict[str, float]:
        return dict(self.values)


TIMEOUT_S = 2.0


def settings(path: Path, **kw: object) -> SondeSettings:
    base: dict[str, object] = {
        "backend": "modbus",
        "port": str(path),
        # Far above a reply's few milliseconds even on a loaded machine: a test that
        # wants a time-out gets one from a sonde that does not answer.
        "timeout_s": TIMEOUT_S,
        "period_s": 4 * TIMEOUT_S,  # a request and its retries fit
        "idle_period_s": 4 * TIMEOUT_S,
        "retries": 0,
        "reconnect_initial_s": 0.05,
        "reconnect_max_s": 0.2,
    }
    return SondeSettings.model_validate(base | kw)


@pytest.fixture
def sonde(tmp_path: Path) -> Iterator[SimulatedSonde]:
    with SimulatedSonde(tmp_path / "ttySONDE", line_out=lambda: 0.0, model=Fixed()) as sim:
        yield sim


async def test_word_order_known_bit_patterns_on_the_wire(sonde: SimulatedSonde) -> None:
    reader = SondeReader(settings(sonde.path))
    try:
        reading = await reader.read()
    finally:
        await reader.close()
    assert reading.status == OK and reading.missing == {}
    assert reading.values == KNOWN
    reply = sonde.last_reply
    # slave 80, function 3, 60 data bytes, then register 40011 onwards, high word first.
    assert reply[:3] == bytes([80, 3, 60])
    data = reply[3:-2]
    assert data[0:4] == bytes.fromhex("3F800000")  # 40011 depth
    assert data[36:40] == bytes.fromhex("C0000000")  # 40029 temperature: (40029-40011)*2
    assert data[56:60] == bytes.fromhex("41C80000")  # 40039 chlorophyll
    assert struct.unpack(">f", data[40:44])[0] == 7.0  # 40031 pH


async def test_one_block_request_per_sample(sonde: SimulatedSonde) -> None:
    reader = SondeReader(settings(sonde.path))
    try:
        readings = [await reader.read() for _ in range(3)]
    finally:
        await reader.close()
    assert [r.requests for r in readings] == [1, 1, 1]
    assert sonde.requests == 3
    assert all(0.0 < r.duration_s < TIMEOUT_S for r in readings)


@pytest.mark.parametrize(
    ("fault", "status"),
    [("timeout", TIMEOUT), ("crc", CRC), ("exception", EXCEPTION)],
)
async def test_failed_reads_are_missing_values_with_reasons(
    sonde: SimulatedSonde, fault: str, status: str
) -> None:
    reader = SondeReader(settings(sonde.path, retries=1))
    try:
        assert (await reader.read()).status == OK
        sonde.fault = fault  # type: ignore[assignment]
        bad = await reader.read()
        sonde.fault = None
        good = await reader.read()
    finally:
        await reader.close()
    assert bad.status == status
    assert bad.values == dict.fromkeys(KNOWN)  # None, never 0.0
    assert bad.missing == dict.fromkeys(KNOWN, status)
    assert bad.error
    if fault != "exception":  # a reply that never arrives is asked again once
        assert bad.requests == 2
    assert good.status == OK and good.values == KNOWN


async def test_nan_is_missing_not_zero(sonde: SimulatedSonde) -> None:
    reader = SondeReader(settings(sonde.path))
    sonde.fault = "nan"
    try:
        reading = await reader.read()
    finally:
        await reader.close()
    assert reading.status == PARTIAL
    assert reading.values["depth"] == 1.0
    assert reading.values["temperature"] is None
    assert reading.missing == {name: "nan" for name in KNOWN if name != "depth"}


async def test_unplugged_adapter_is_reopened(sonde: SimulatedSonde) -> None:
    reader = SondeReader(settings(sonde.path))
    try:
        assert (await reader.read()).status == OK
        sonde.unplug()
        down = [await reader.read() for _ in range(3)]
        assert all(r.status == DISCONNECTED for r in down)
        assert all(r.values == dict.fromkeys(KNOWN) for r in down)
        assert not reader.up and reader.losses == 1
        sonde.replug()
        deadline = time.monotonic() + 30  # reopened with backoff: reads until it is
        while (reading := await reader.read()).status != OK:
            assert time.monotonic() < deadline, reading
            await asyncio.sleep(0.05)
        assert reading.status == OK and reading.values == KNOWN
        assert reader.up and reader.opens == 2
    finally:
        await reader.close()


async def test_a_port_that_is_not_there_is_retried_with_backoff(tmp_path: Path) -> None:
    reader = SondeReader(settings(tmp_path / "nothing-here"))
    readings = [await reader.read() for _ in range(3)]
    assert [r.status for r in readings] == [DISCONNECTED] * 3
    assert readings[0].error and "nothing-here" in readings[0].error
    # A cast never waits for a missing sonde: no read waits out its time-out.
    assert all(r.duration_s < TIMEOUT_S for r in readings)
    await reader.close()


async def test_a_sonde_mapping_only_its_values_is_read_by_itself(tmp_path: Path) -> None:
    """pymodbus's own server mapping only 40011-12 and 40029-40040: exception 2 for
    the one 30-register block; the reader reads the mapped blocks from then on."""
    with SimulatedSonde(
        tmp_path / "ttySONDE", line_out=lambda: 0.0, model=Fixed(), only_mapped=True
    ) as sim:
        reader = SondeReader(settings(sim.path))
        try:
            readings = [await reader.read() for _ in range(3)]
        finally:
            await reader.close()
    assert [r.status for r in readings] == [OK, OK, OK]
    assert all(r.values == KNOWN for r in readings)
    assert [r.requests for r in readings] == [3, 2, 2]
    assert [(b.address, b.count) for b in reader.blocks] == [(10, 2), (28, 12)]


async def test_the_october_2025_map_by_protocol_address(tmp_path: Path) -> None:
    """The group's new map (raw addresses 30101, 31001 ... 31601) against pymodbus."""
    names = ["depth", "temperature", "ph", "do_saturation", "do_concentration", "blue",
             "chlorophyll", "conductivity"]  # fmt: skip
    addresses = [30101, *range(31001, 31602, 100)]
    params = [
        {"name": n, "address": a, "unit": "1", "long_name": n}
        for n, a in zip(names, addresses, strict=True)
    ]
    s = settings(tmp_path / "ttySONDE", parameters=params, retries=1)

    class Values:
        def read(self, line_out_m: float, t: float) -> dict[str, float]:
            return {n: float(i) + 0.5 for i, n in enumerate(names)}

    with SimulatedSonde(
        tmp_path / "ttySONDE", line_out=lambda: 0.0, model=Values(),
        parameters=s.parameters, only_mapped=True,
    ) as sim:  # fmt: skip
        reader = SondeReader(s)
        try:
            first, second = [await reader.read() for _ in range(2)]
        finally:
            await reader.close()
        assert sim.requests >= 8
    assert first.status == second.status == OK
    assert second.values == {n: float(i) + 0.5 for i, n in enumerate(names)}


def _bytes_waiting(fd: int) -> bytes:
    try:
        return os.read(fd, 256)
    except BlockingIOError:
        return b""


async def test_a_cancel_that_meets_a_reply_is_not_lost(tmp_path: Path) -> None:
    """A daemon stopping as the sonde's reply comes in: the reader's wait is cancelled in
    the very turn of the loop in which the reply was noticed. Python 3.11's
    asyncio.wait_for returned the reply then and dropped the cancel, so the sonde's duty
    sampled on for ever and the daemon never stopped (seen under load: a simulation
    still "shutting down" 140 s later)."""
    with PtyPair(tmp_path / "ttySONDE") as pty:
        reader = SondeReader(settings(pty.path))
        task = asyncio.create_task(reader.read())
        try:
            # The request written: the reader waits for its reply from here on.
            await until(lambda: _bytes_waiting(pty.master_fd), what="the request on the wire")
            port = reader._port  # what the reader waits on: its reply's bytes noticed
            assert port is not None
            port.arrived.set()
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
        finally:
            if not task.done():
                task.cancel()
            await reader.close()
