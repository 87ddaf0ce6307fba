"""The sonde reader against an independent Modbus RTU responder written here.

The project's simulated sonde (pymodbus's server) always answers the right
way at once; the faults a real RS-485 line shows need bytes the server never
sends. The responder below reads requests off a real pty, checks their CRC
with its own CRC code (not the project's) and answers as each test tells it:
another function code, another slave, a wrong byte count, late, or with
exception 2 for any register it does not map. Every register holds the index
of the request it answers, so a value taken for the wrong request shows.

Every time below is a multiple of `S`: the same scenario as at 0.1 s time-outs and
0.4 s periods, stretched so that a loaded machine, which can keep this process off
the CPU for tens of milliseconds, never turns a prompt reply into a late one.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import struct
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from cc_daemon.config.sonde import SondeSettings
from cc_daemon.drivers.sonde.reader import (
    DISCONNECTED,
    EXCEPTION,
    LATE,
    NO_TIME,
    OK,
    RESYNC,
    TIMEOUT,
    WRONG_FUNCTION,
    WRONG_LENGTH,
    WRONG_SLAVE,
    SondeReader,
)
from cc_daemon.sim.pty import make_raw

S = 6.0  # the scenarios' time scale: a time-out of 0.1 s becomes 0.1 * S


def crc(frame: bytes) -> bytes:
    # Written from the Modbus over serial line spec, section 6.2.2, independently.
    value = 0xFFFF
    for b in frame:
        value ^= b
        for _ in range(8):
            lsb = value & 1
            value >>= 1
            if lsb:
                value ^= 0xA001
    return struct.pack("<H", value)


@dataclass
class Request:
    index: int
    slave: int
    function: int
    address: int
    count: int
    at: float


@dataclass
class Responder:
    """Answers every request with `answer(request)`: (delay s, bytes) or None."""

    master: int
    answer: Callable[[Request], tuple[float, bytes] | None]
    requests: list[Request] = field(default_factory=list)
    _rx: bytes = b""

    def readable(self) -> None:
        try:
            self._rx += os.read(self.master, 256)
        except OSError:
            return
        while len(self._rx) >= 8:
            frame, self._rx = self._rx[:8], self._rx[8:]
            assert crc(frame[:6]) == frame[6:], f"bad request CRC: {frame.hex()}"
            slave, function, address, count = struct.unpack(">BBHH", frame[:6])
            req = Request(len(self.requests), slave, function, address, count, time.monotonic())
            self.requests.append(req)
            reply = self.answer(req)
            if reply is not None:
                delay, data = reply
                asyncio.get_running_loop().call_later(delay, os.write, self.master, data)


def registers_reply(slave: int, function: int, registers: list[int]) -> bytes:
    body = struct.pack(">BBB", slave, function, 2 * len(registers))
    body += b"".join(struct.pack(">H", r) for r in registers)
    return body + crc(body)


def exception_reply(slave: int, function: int, code: int) -> bytes:
    body = bytes([slave, function | 0x80, code])
    return body + crc(body)


def index_registers(req: Request) -> list[int]:
    """Every float in the reply is the request's index (high word first)."""
    hi, lo = struct.unpack(">HH", struct.pack(">f", float(req.index)))
    return [hi if (req.address + i) % 2 == 0 else lo for i in range(req.count)]


def prompt(req: Request) -> tuple[float, bytes]:
    return 0.005 * S, registers_reply(req.slave, req.function, index_registers(req))


@pytest.fixture
async def line(tmp_path: Path) -> AsyncIterator[tuple[str, Callable[..., Responder]]]:
    master, slave = os.openpty()
    make_raw(slave)
    loop = asyncio.get_running_loop()
    holder: list[Responder] = []

    def start(answer: Callable[[Request], tuple[float, bytes] | None]) -> Responder:
        responder = Responder(master, answer)
        holder.append(responder)
        loop.add_reader(master, responder.readable)
        return responder

    yield os.ttyname(slave), start
    if holder:
        loop.remove_reader(master)
    os.close(slave)
    with contextlib.suppress(OSError):  # a test may have pulled the plug already
        os.close(master)


# An even-address map, so "index_registers" puts each float's high word first.
EVEN_MAP = [
    {"name": "depth", "address": 10, "unit": "m", "long_name": "d"},
    {"name": "temperature", "address": 28, "unit": "degC", "long_name": "t"},
    {"name": "ph", "address": 30, "unit": "1", "long_name": "p"},
]


def settings(port: str, **kw: object) -> SondeSettings:
    base: dict[str, object] = {
        "backend": "modbus",
        "port": port,
        "timeout_s": 0.1 * S,
        "retries": 0,
        "period_s": 0.4 * S,
        "parameters": EVEN_MAP,
    }
    return SondeSettings.model_validate(base | kw)


async def read_n(reader: SondeReader, n: int, period: float) -> list:  # type: ignore[type-arg]
    """`n` readings on a steady beat, as the sampler takes them."""
    out = []
    start = time.monotonic()
    try:
        for k in range(n):
            await asyncio.sleep(max(0.0, start + k * period - time.monotonic()))
            out.append(await reader.read())
    finally:
        await reader.close()
    return out


@pytest.mark.parametrize(
    ("make_reply", "status"),
    [
        # A reply with function 04 to a 03 request: right length, right slave, valid CRC.
        (lambda r: registers_reply(r.slave, 0x04, index_registers(r)), WRONG_FUNCTION),
        # Another slave answers (valid CRC): not line noise.
        (lambda r: registers_reply(r.slave + 1, r.function, index_registers(r)), WRONG_SLAVE),
        # One register short.
        (lambda r: registers_reply(r.slave, r.function, index_registers(r)[:-1]), WRONG_LENGTH),
    ],
    ids=["function_04", "other_slave", "short"],
)
async def test_a_valid_frame_that_is_not_the_answer_is_never_ok(
    line: tuple[str, Callable[..., Responder]],
    make_reply: Callable[[Request], bytes],
    status: str,
) -> None:
    port, start = line
    start(lambda r: (0.005 * S, make_reply(r)))
    (reading,) = await read_n(SondeReader(settings(port, retries=1)), 1, 0.4 * S)
    assert reading.status == status
    assert reading.values == dict.fromkeys(["depth", "temperature", "ph"])
    assert reading.requests == 1  # the sonde answered: asking again changes nothing
    assert reading.error


async def test_late_replies_are_never_taken_for_a_later_request(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    # Every reply comes 0.85 s late: two periods and more after its request
    # (the field's 2.1 s late replies at a 1 s period, scaled down).
    port, start = line
    responder = start(lambda r: (0.85 * S, prompt(r)[1]))
    readings = await read_n(SondeReader(settings(port)), 8, 0.4 * S)
    assert not [r for r in readings if r.status == OK]
    late = [x for r in readings for x in r.late]
    assert late, "the late replies are kept, flagged"
    for x in late:
        assert x.status == LATE and x.duration_s > 0.1 * S
        asked = responder.requests[int(x.values["depth"] or 0)]
        # Stamped with the time it was asked for, not the time it came (0.85 * S later).
        assert abs(x.mono_s - asked.at) < 0.1 * S
        assert x.values["temperature"] == x.values["depth"]


async def test_a_dropped_request_costs_one_reading_and_nothing_is_misattributed(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    port, start = line
    # The first request is lost on the line; its answer comes 0.5 s late, inside
    # the next request's window. Every other request is answered at once.
    responder = start(lambda r: (0.5 * S, prompt(r)[1]) if r.index == 0 else prompt(r))
    readings = await read_n(SondeReader(settings(port)), 4, 0.4 * S)
    assert readings[0].status == TIMEOUT
    assert [r.status for r in readings[1:]] == [OK, OK, OK]
    for r in readings[1:]:
        # Each value is from a request sent during its own reading.
        for value in r.values.values():
            assert value is not None
            assert r.mono_s - 0.001 <= responder.requests[int(value)].at <= r.mono_s + 0.2 * S
    (late,) = [x for r in readings for x in r.late]
    assert late.values["depth"] == 0.0 and abs(late.mono_s - readings[0].mono_s) < 0.1 * S
    # While the first request was owed, the next was asked in other sizes than 22 registers.
    assert responder.requests[1].count != 22


async def test_exception_2_for_gaps_reads_mapped_blocks_by_itself(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    port, start = line
    mapped = {10, 11, 28, 29, 30, 31}

    def answer(r: Request) -> tuple[float, bytes]:
        if not set(range(r.address, r.address + r.count)) <= mapped:
            return 0.005 * S, exception_reply(r.slave, r.function, 2)
        return prompt(r)

    responder = start(answer)
    readings = await read_n(SondeReader(settings(port)), 2, 0.4 * S)
    assert [r.status for r in readings] == [OK, OK]
    assert [(q.address, q.count) for q in responder.requests] == [
        (10, 22),  # the one block, refused
        (10, 2), (28, 4),  # gapless blocks, this reading
        (10, 2), (28, 4),  # and from then on
    ]  # fmt: skip


async def test_malacate_map_one_value_per_request(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    # The group's October 2025 map: protocol addresses, a sonde that answers
    # only reads of exactly one value.
    port, start = line
    addresses = [30101, 31001, 31101, 31201, 31301, 31401, 31501, 31601]

    def answer(r: Request) -> tuple[float, bytes]:
        if r.address not in addresses or r.count != 2:
            return 0.005 * S, exception_reply(r.slave, r.function, 2)
        return 0.005 * S, registers_reply(r.slave, r.function, [0x4120, 0x0000])  # 10.0

    start(answer)
    params = [
        {"name": f"v{i}", "address": a, "unit": "1", "long_name": "x"}
        for i, a in enumerate(addresses)
    ]
    s = settings(port, parameters=params, depth_parameter="v0", period_s=1.0 * S)
    readings = await read_n(SondeReader(s), 2, 1.0 * S)
    assert [r.status for r in readings] == [OK, OK]
    assert readings[1].values == dict.fromkeys([f"v{i}" for i in range(8)], 10.0)
    assert readings[1].requests == 8


async def test_a_retry_that_cannot_fit_in_the_period_is_skipped(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    port, start = line
    responder = start(lambda r: None)  # a silent sonde
    # Malacate's 0.5 s wait with one retry at 1 s: the retry would end at the period.
    s = settings(port, timeout_s=0.5 * S, retries=1, period_s=1.0 * S)
    (reading,) = await read_n(SondeReader(s), 1, 1.0 * S)
    assert reading.status == TIMEOUT and reading.requests == 1
    assert reading.duration_s < 1.0 * S
    assert len(responder.requests) == 1


async def test_a_retry_that_fits_is_sent(line: tuple[str, Callable[..., Responder]]) -> None:
    port, start = line
    responder = start(lambda r: None if r.index == 0 else prompt(r))
    s = settings(port, timeout_s=0.1 * S, retries=1, period_s=0.4 * S)
    (reading,) = await read_n(SondeReader(s), 1, 0.4 * S)
    # The retry is asked in two parts (the first request may still answer late).
    assert reading.status == OK and reading.requests == 3
    assert [q.count for q in responder.requests] == [22, 18, 4]


async def test_exception_other_than_2_is_not_split(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    port, start = line
    responder = start(lambda r: (0.005 * S, exception_reply(r.slave, r.function, 4)))
    (reading,) = await read_n(SondeReader(settings(port)), 1, 0.4 * S)
    assert reading.status == EXCEPTION and len(responder.requests) == 1


async def test_requests_that_cannot_end_within_the_period_are_not_sent(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    port, start = line
    responder = start(lambda r: None)  # silent: each block costs a whole time-out
    params = [
        {"name": f"v{b}{i}", "address": 200 * b + 2 * i, "unit": "1", "long_name": "x"}
        for b, n in enumerate((2, 3, 4))
        for i in range(n)
    ]
    s = settings(
        port, parameters=params, depth_parameter="v00", timeout_s=0.4 * S, period_s=1.0 * S
    )
    (reading,) = await read_n(SondeReader(s), 1, 1.0 * S)
    assert [q.count for q in responder.requests] == [4, 6]
    assert reading.duration_s < 1.0 * S
    assert list(reading.missing.values()) == [TIMEOUT] * 5 + [NO_TIME] * 4


async def test_a_silent_sonde_with_one_value_per_block_is_not_asked_ambiguously(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    port, start = line
    responder = start(lambda r: None)
    params = [
        {"name": f"v{i}", "address": 200 * i, "unit": "1", "long_name": "x"} for i in range(4)
    ]
    s = settings(port, parameters=params, depth_parameter="v0", timeout_s=0.1 * S, period_s=1.0 * S)
    (reading,) = await read_n(SondeReader(s), 1, 1.0 * S)
    # v0 asked whole (2 registers), v1 in halves (the first half times out): after
    # that every size is owed a reply that may still come, so nothing is asked.
    assert [q.count for q in responder.requests] == [2, 1]
    assert list(reading.missing.values()) == [TIMEOUT, TIMEOUT, RESYNC, RESYNC]


async def test_a_port_lost_in_the_middle_of_a_reading_ends_it_as_disconnected(
    line: tuple[str, Callable[..., Responder]],
) -> None:
    port, start = line
    master: list[int] = []

    def answer_then_unplug(r: Request) -> tuple[float, bytes]:
        asyncio.get_running_loop().remove_reader(master[0])
        asyncio.get_running_loop().call_later(0.05 * S, os.close, master[0])  # after the reply
        return prompt(r)

    responder = start(answer_then_unplug)
    master.append(responder.master)
    params = [
        {"name": f"v{i}", "address": 200 * i, "unit": "1", "long_name": "x"} for i in range(3)
    ]
    s = settings(port, parameters=params, depth_parameter="v0", timeout_s=0.1 * S, period_s=1.0 * S)
    (reading,) = await read_n(SondeReader(s), 1, 1.0 * S)
    assert reading.values["v0"] == 0.0 and reading.status == DISCONNECTED
    assert reading.missing == {"v1": DISCONNECTED, "v2": DISCONNECTED}


@dataclass
class View:
    phase: str = "descending"
    cast_id: int | None = 1
    probe_depth_m: float = 0.0


async def test_the_duty_journals_late_replies_flagged_at_the_time_asked(
    line: tuple[str, Callable[..., Responder]], tmp_path: Path
) -> None:
    from cc_daemon.config import Settings
    from cc_daemon.daemon.sonde import SondeDuty
    from cc_daemon.ground.clock import SystemClock
    from cc_daemon.store import Journal, JournalReader

    port, start = line
    start(lambda r: (0.85 * S, prompt(r)[1]))
    settings = Settings.model_validate(
        {"sonde": settings_dict(port), "store": {"path": str(tmp_path / "j.db")}}
    )
    journal = Journal(tmp_path / "j.db")
    journal.open()
    view = View()
    duty = SondeDuty(
        settings, clock=SystemClock(), journal=journal, view=lambda: view,
        on_bottom_contact=lambda depth: None,
    )  # fmt: skip
    began = time.monotonic()
    try:
        for k in range(8):
            await asyncio.sleep(max(0.0, began + 0.4 * S * k - time.monotonic()))
            view.probe_depth_m = float(k)
            await duty.sample(view)
    finally:
        await duty.reader.close()
        journal.close()
    with JournalReader(tmp_path / "j.db") as reader:
        rows = reader.sonde_samples()
    assert "ok" not in {r.status for r in rows}
    late = [r for r in rows if r.status == "late"]
    assert late
    asked = {r.mono_s: r.line_out_m for r in rows if r.status != "late"}
    for r in late:
        # The line out of the reading it was asked in, at or just after the reading's start.
        started = max(m for m in asked if m <= r.mono_s + 1e-6)
        assert r.line_out_m == asked[started] and r.mono_s - started < 0.4 * S
    assert duty._latest_depth is None  # never used for R-M


def settings_dict(port: str) -> dict[str, object]:
    return {
        "backend": "modbus",
        "port": port,
        "timeout_s": 0.1 * S,
        "retries": 0,
        "period_s": 0.4 * S,
        "idle_period_s": 1.0 * S,
        "parameters": EVEN_MAP,
    }
