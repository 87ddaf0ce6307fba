"""The sonde's Modbus RTU link: open it, read the register map, say what went wrong.

This module owns the sonde's serial port and its request/reply exchanges
(frames: `rtu`) and turns one sampling request into a `SondeReading`: every
parameter either a number or missing with a reason (`timeout`; `crc` - bytes
came back but no valid frame -; `exception` - the sonde answered with a Modbus
exception -; `wrong_slave`, `wrong_function`, `wrong_length` - a valid frame
that is not the answer to the request -; `nan`; `disconnected`; `no_time` -
the period was spent before the request could be sent -). A reply is good only
if it comes from `slave_id`, with function 3 and the byte count asked for.

Modbus RTU has no transaction id: a reply that comes after its request's
time-out would be taken for the answer to the next, identical request. The
reader drains stale bytes before each request and remembers the requests that
timed out (`_owed`, for `LATE_LIMIT_S`); while one is owed, no request of the
same size is sent: the block is asked in two parts of other sizes (split at a
value's boundary, else at a register), so a reply's byte count says which
request it answers. A late reply to a whole block is returned apart as a `late`
reading stamped with the time it was asked for; one that fits no request is
dropped. When no shape is free the block is not asked (`resync`).

It reads the whole map in the fewest block requests (`registers.plan_blocks`);
a sonde that refuses unmapped registers (exception 2 for a block with gaps) is
then read in gapless blocks, and if it refuses those too, one value at a time,
by itself, said once in the log. A request or retry is sent only if its
time-out ends within `period_s` of the reading's start.

The link is supervised here: a port that fails to open or is lost is closed,
logged once, and reopened with capped, jittered, doubling delays, tried only
from `read()`. It never journals (the sampler does) and never turns a failure
into a number.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import serial_asyncio
import structlog

from cc_daemon.config.sonde import SondeSettings
from cc_daemon.drivers.sonde.registers import Block, decode, plan_blocks
from cc_daemon.drivers.sonde.rtu import READ_HOLDING, Reply, ReplyParser, read_request

_log = structlog.get_logger("cc_daemon.sonde")

OK = "ok"
PARTIAL = "partial"  # some values NaN
TIMEOUT = "timeout"
CRC = "crc"
EXCEPTION = "exception"
DISCONNECTED = "disconnected"
WRONG_SLAVE = "wrong_slave"
WRONG_FUNCTION = "wrong_function"
WRONG_LENGTH = "wrong_length"
NO_TIME = "no_time"
LATE = "late"  # a reply after its request's time-out, stamped with the request's time
RESYNC = "resync"  # not asked: every request shape would be ambiguous with an owed one

ILLEGAL_DATA_ADDRESS = 2  # the Modbus exception code for an unmapped register
# A request that timed out may still be answered for this long (the field saw
# replies 2.0 and 2.7 s late); meanwhile no request of its size is sent.
LATE_LIMIT_S = 10.0
_RX_LIMIT = 4096  # bytes kept from the port between reads (a babbling line is bounded)


@dataclass(frozen=True, slots=True)
class SondeReading:
    """One sample of every parameter, requested at `mono_s`."""

    mono_s: float
    wall_s: float
    duration_s: float
    status: str
    values: dict[str, float | None]
    missing: dict[str, str] = field(default_factory=dict)  # name -> why it is missing
    error: str | None = None
    requests: int = 0  # block requests sent (retries included)
    # Replies to earlier requests that came after their time-out: `late` readings
    # stamped with the time each was asked for, holding only that request's values.
    late: tuple[SondeReading, ...] = ()

    def value(self, name: str) -> float | None:
        return self.values.get(name)


class _Owed(NamedTuple):
    """A request that timed out: its answer may still come."""

    size: int  # registers asked for
    block: Block | None  # the whole block, or None for a part of one
    sent: float  # loop time
    mono_s: float
    wall_s: float


class _Port(asyncio.Protocol):
    """Bytes from the port into a bounded buffer; the reader waits on `arrived`."""

    def __init__(self) -> None:
        self.transport: asyncio.Transport | None = None
        self.rx = bytearray()
        self.arrived = asyncio.Event()
        self.lost: str | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.rx += data
        if len(self.rx) > _RX_LIMIT:
            del self.rx[: len(self.rx) - _RX_LIMIT]
        self.arrived.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = f"{type(exc).__name__}: {exc}" if exc else "the port closed"
        self.arrived.set()

    def take(self) -> bytes:
        data = bytes(self.rx)
        self.rx.clear()
        self.arrived.clear()
        return data


class SondeReader:
    """The sonde on `settings.port`. `await read()` as often as the sampler likes."""

    def __init__(
        self,
        settings: SondeSettings,
        *,
        monotonic: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        rng: random.Random | None = None,
    ) -> None:
        self.settings = settings
        self.blocks: list[Block] = plan_blocks(settings.parameters)
        self.names = [p.name for p in settings.parameters]
        self._monotonic = monotonic
        self._wall = wall
        self._rng = rng or random.Random()
        self._port: _Port | None = None
        self._delay = settings.reconnect_initial_s
        self._next_open = -float("inf")
        self.up = False
        self.losses = 0
        self.opens = 0
        self.requests = 0
        self.last_reason: str | None = None
        self._owed: deque[_Owed] = deque()
        self._word_split_refused = False
        self._exception_code: int | None = None
        self.late_replies = 0
        self.stale_bytes = 0
        self._late_said = False

    # ------------------------------------------------------------ the link

    async def _ensure_open(self, now: float) -> str | None:
        """Open the port if it is time to try; None when open, else why not."""
        if self._port is not None and self._port.lost is None:
            return None
        if self._port is not None:
            self._lost(self._port.lost or "the port closed (adapter unplugged?)")
        if now < self._next_open:
            return self.last_reason or "port not open"
        s = self.settings
        port = _Port()
        try:
            transport, _ = await serial_asyncio.create_serial_connection(
                asyncio.get_running_loop(),
                lambda: port,
                s.port,
                baudrate=s.baudrate,
                bytesize=8,
                parity=s.parity,
                stopbits=s.stopbits,
            )
        except Exception as exc:  # pyserial raises whatever the OS said
            reason = f"{type(exc).__name__}: {exc}"
            self._schedule_reopen(now)
            if reason != self.last_reason:
                _log.warning("sonde port not open; retrying", port=s.port, reason=reason)
            self.last_reason = reason
            return reason
        assert isinstance(transport, asyncio.Transport)
        port.transport = transport  # connection_made may come a loop turn later
        self._port = port
        self._owed.clear()
        self._delay = s.reconnect_initial_s
        self.up = True
        self.opens += 1
        _log.info("sonde port open", port=s.port, baudrate=s.baudrate, slave_id=s.slave_id)
        return None

    def _schedule_reopen(self, now: float) -> None:
        # Jittered so several devices on one hub do not retry in step.
        self._next_open = now + self._delay * self._rng.uniform(0.8, 1.2)
        self._delay = min(self._delay * 2, self.settings.reconnect_max_s)

    def _lost(self, reason: str) -> None:
        port, self._port = self._port, None
        if port is not None and port.transport is not None:
            port.transport.close()
        if self.up:
            self.losses += 1
            _log.warning("sonde port lost; reopening", port=self.settings.port, reason=reason)
        self.up = False
        self.last_reason = reason
        self._schedule_reopen(self._monotonic())

    async def close(self) -> None:
        port, self._port = self._port, None
        if port is not None and port.transport is not None:
            port.transport.close()
            await asyncio.sleep(0)  # let the transport close its file descriptor
        self.up = False

    # ------------------------------------------------------------ a sample

    async def read(self) -> SondeReading:
        """Every parameter now, or why not. Never raises for a sonde or port fault."""
        loop = asyncio.get_running_loop()
        start = self._monotonic()
        wall = self._wall()
        # A request is sent only if its time-out ends within the period.
        deadline = loop.time() + self.settings.period_s
        requests_before = self.requests
        values: dict[str, float | None] = dict.fromkeys(self.names)
        missing: dict[str, str] = {}
        late: list[SondeReading] = []
        status, error = OK, None
        why_closed = await self._ensure_open(start)
        if why_closed is not None:
            status, error = DISCONNECTED, why_closed
            missing = dict.fromkeys(self.names, DISCONNECTED)
        else:
            late += self._drain()  # before expiring: a reply that came in the gap is kept
            self._expire(loop.time())
            queue = list(self.blocks)
            while queue:
                block = queue.pop(0)
                got, failure = await self._read_block(block, deadline, late)
                if failure is None:
                    values.update(got)
                    continue
                if failure[0] == EXCEPTION and self._refuses_gaps(block):
                    queue[0:0] = self._split(block)
                    continue
                status, error = failure
                missing.update((p.name, status) for p in block.parameters)
        for name, value in values.items():
            if value is None and name not in missing:
                missing[name] = "nan"
        if status == OK and missing:
            status = PARTIAL
        if status != self.last_reason and status in (OK, PARTIAL) and self.last_reason:
            _log.info("sonde answering again", after=self.last_reason)
        if status in (OK, PARTIAL):
            self.last_reason = None
        elif status not in (DISCONNECTED, RESYNC, self.last_reason):
            _log.warning("sonde reading failed", status=status, error=error)
            self.last_reason = status
        return SondeReading(
            mono_s=start,
            wall_s=wall,
            duration_s=self._monotonic() - start,
            status=status,
            values=values,
            missing=missing,
            error=error,
            requests=self.requests - requests_before,
            late=tuple(late),
        )

    # ------------------------------------------------------------ blocks

    def _refuses_gaps(self, block: Block) -> bool:
        return self._exception_code == ILLEGAL_DATA_ADDRESS and len(block.parameters) > 1

    def _split(self, block: Block) -> list[Block]:
        """Smaller blocks for a sonde that refused `block` as illegal (exception 2)."""
        if block.has_gaps:
            parts = plan_blocks(block.parameters, gaps=False)
            how = "in blocks of mapped registers only"
        else:
            parts = [Block(p.address, p.count, (p,)) for p in block.parameters]
            how = "one value per request"
        if len(parts) == 1:  # gapless already and one parameter: nothing smaller
            parts = [Block(p.address, p.count, (p,)) for p in block.parameters]
            how = "one value per request"
        _log.warning(
            "the sonde refuses a block read (exception 2, illegal data address); "
            "reading it " + how + " from now on",
            address=block.address,
            count=block.count,
            requests=len(parts),
        )
        self.blocks = sorted(
            [b for b in self.blocks if b is not block] + parts, key=lambda b: b.address
        )
        return parts

    async def _read_block(
        self, block: Block, deadline: float, late: list[SondeReading]
    ) -> tuple[dict[str, float | None], tuple[str, str] | None]:
        loop = asyncio.get_running_loop()
        timeout = self.settings.timeout_s
        failure = (NO_TIME, f"no time left in the {self.settings.period_s:g} s period")
        for _attempt in range(1 + self.settings.retries):
            if self._port is None:  # lost during this reading: the rest cannot be asked
                return {}, (DISCONNECTED, self.last_reason or "the port closed")
            shape = self._shape(block)
            if shape is None:
                return {}, (RESYNC, "every request shape is owed a late reply; not asked")
            if loop.time() + timeout * len(shape) > deadline:
                break  # a retry (or a request) that cannot end within the period is skipped
            registers: list[int] = []
            for address, count in shape:
                if self._port is None:
                    outcome: list[int] | tuple[str, str] = (DISCONNECTED, "the port closed")
                    failure = outcome
                    break
                outcome = await self._ask(address, count, block if len(shape) == 1 else None, late)
                if isinstance(outcome, tuple):
                    if outcome[0] == EXCEPTION and len(shape) > 1 and shape[0][1] % 2:
                        self._word_split_refused = True  # it will not split a value
                    failure = outcome
                    break
                registers += outcome
            else:
                return decode(block, registers), None
            if failure[0] not in (TIMEOUT, CRC):
                break  # the sonde answered, or the port is gone: asking again changes nothing
        return {}, failure

    def _shape(self, block: Block) -> list[tuple[int, int]] | None:
        """The requests for `block`: none of a size that a late reply could still have."""
        owed = {o.size for o in self._owed}
        a, c = block.address, block.count
        if c not in owed:
            return [(a, c)]
        cuts = [p.address - a for p in block.parameters if p.address > a]
        if not self._word_split_refused:
            cuts += [c - 1, 1]
        for k in cuts:
            if 0 < k < c and k not in owed and c - k not in owed:
                return [(a, k), (a + k, c - k)]
        return None

    async def _ask(
        self, address: int, count: int, block: Block | None, late: list[SondeReading]
    ) -> list[int] | tuple[str, str]:
        """One request and its reply's registers, or (reason, words)."""
        port = self._port
        assert port is not None and port.transport is not None
        loop = asyncio.get_running_loop()
        slave = self.settings.slave_id
        late += self._drain()
        sent, mono_s, wall_s = loop.time(), self._monotonic(), self._wall()
        try:
            port.transport.write(read_request(slave, address, count))
        except OSError as exc:
            self._lost(f"{type(exc).__name__}: {exc}")
            return DISCONNECTED, str(exc)
        self.requests += 1
        self._exception_code = None
        parser = ReplyParser()
        end = sent + self.settings.timeout_s
        while True:
            for reply in parser.feed(port.take()):
                if reply.slave != slave:
                    return WRONG_SLAVE, f"slave {reply.slave} answered; slave_id is {slave}"
                if reply.exception is not None:
                    self._exception_code = reply.exception
                    return EXCEPTION, f"exception response code {reply.exception}"
                if reply.function != READ_HOLDING:
                    return (
                        WRONG_FUNCTION,
                        f"a reply with function {reply.function:02d} to a function 03 request",
                    )
                if len(reply.data) == 2 * count:
                    return reply.registers
                owed = self._owed_for(reply)
                if owed is not None:
                    late += self._late(owed, reply, loop.time())
                    continue
                return WRONG_LENGTH, f"{len(reply.data)} data bytes, asked for {2 * count}"
            if port.lost is not None:
                reason = port.lost
                self._lost(reason)
                return DISCONNECTED, reason
            left = end - loop.time()
            if left <= 0:
                break
            # Not asyncio.wait_for: on Python 3.11 it returns, swallowing a cancel, when
            # what it waits for completes in the same turn of the loop (a reply arriving
            # as the daemon stops), and the sonde's duty then sampled on for ever.
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(left):
                    await port.arrived.wait()
        if parser.pending or parser.dropped:
            # Bytes came: the sonde answered, garbled. Its late answer is not owed.
            n = parser.pending + parser.dropped
            return CRC, f"{n} bytes but no valid reply (bad CRC?)"
        self._owed.append(_Owed(count, block, sent, mono_s, wall_s))
        return TIMEOUT, f"no reply in {self.settings.timeout_s:g} s"

    # ------------------------------------------------------------ late replies

    def _expire(self, now: float) -> None:
        while self._owed and now - self._owed[0].sent > LATE_LIMIT_S:
            self._owed.popleft()

    def _owed_for(self, reply: Reply) -> _Owed | None:
        """The oldest timed-out request this reply can answer (it is then settled)."""
        if (
            reply.slave != self.settings.slave_id
            or reply.function != READ_HOLDING
            or reply.exception is not None
        ):
            return None
        for owed in self._owed:  # at most one per size: no request repeats an owed size
            if len(reply.data) == 2 * owed.size:
                self._owed.remove(owed)
                return owed
        return None

    def _drain(self) -> list[SondeReading]:
        """Bytes that came between requests: late replies, or noise to forget."""
        port = self._port
        if port is None:
            return []
        data = port.take()
        if not data:
            return []
        loop = asyncio.get_running_loop()
        parser = ReplyParser()
        late: list[SondeReading] = []
        stale = len(data)
        for reply in parser.feed(data):
            owed = self._owed_for(reply)
            if owed is not None:
                late += self._late(owed, reply, loop.time())
                stale -= 5 + len(reply.data)
        if stale:
            self.stale_bytes += stale
            _log.debug("sonde: stale bytes dropped before a request", count=stale)
        return late

    def _late(self, owed: _Owed, reply: Reply, arrived: float) -> list[SondeReading]:
        """The late reading a reply to `owed` makes (none for a part of a block)."""
        self.late_replies += 1
        after = arrived - owed.sent
        if owed.block is None:
            return []
        if not self._late_said:
            _log.warning(
                "the sonde answers after the time-out; its replies are kept as late readings "
                "(raise sonde.timeout_s)",
                after_s=round(after, 3),
                timeout_s=self.settings.timeout_s,
            )
            self._late_said = True
        values: dict[str, float | None] = dict.fromkeys(self.names)
        values.update(decode(owed.block, reply.registers))
        asked = {p.name for p in owed.block.parameters}
        missing = {n: "not_asked" for n in self.names if n not in asked}
        missing.update((n, "nan") for n in asked if values[n] is None)
        reading = SondeReading(
            mono_s=owed.mono_s,
            wall_s=owed.wall_s,
            duration_s=after,
            status=LATE,
            values=values,
            missing=missing,
            error=f"answered {after:.3f} s after the request (timeout_s = "
            f"{self.settings.timeout_s:g})",
        )
        return [reading]
