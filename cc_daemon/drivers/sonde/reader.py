"""The sonde's Modbus RTU link: open it, read the register map, say what went wrong.

This module owns the pymodbus asyncio RTU client (its framer, timeout and
retries) and turns one sampling request into a `SondeReading`: every parameter
either a number or missing with a reason (`timeout`, `crc` - bytes came back
but no valid frame -, `exception` - the sonde answered with a Modbus exception
-, `nan`, or `disconnected`). It reads the whole map in the fewest block
requests (`registers.plan_blocks`).

The link is supervised here: a port that fails to open or is lost is closed,
logged once, and reopened with capped, jittered, doubling delays, tried only
from `read()` so a caller is never kept waiting longer than one request's
`timeout_s x (retries + 1)`. It never sleeps between attempts itself, never
journals (the sampler does) and never turns a failure into a number.
"""

from __future__ import annotations

import logging
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import structlog
from pymodbus import FramerType, ModbusException
from pymodbus.client import AsyncModbusSerialClient
from pymodbus.exceptions import ConnectionException
from pymodbus.pdu import ExceptionResponse

from cc_daemon.config.sonde import SondeSettings
from cc_daemon.drivers.sonde.registers import Block, plan_blocks

_log = structlog.get_logger("cc_daemon.sonde")

# pymodbus logs every failed request at ERROR with a dump of recent frames; the
# reader reports failures itself, once per change, with the reason.
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

OK = "ok"
PARTIAL = "partial"  # some values NaN
TIMEOUT = "timeout"
CRC = "crc"
EXCEPTION = "exception"
DISCONNECTED = "disconnected"


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

    def value(self, name: str) -> float | None:
        return self.values.get(name)


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
        self._client: AsyncModbusSerialClient | None = None
        self._delay = settings.reconnect_initial_s
        self._next_open = -float("inf")
        self.up = False
        self.losses = 0
        self.opens = 0
        self.requests = 0
        self._rx_bytes = 0
        self.last_reason: str | None = None

    # ------------------------------------------------------------ the link

    async def _ensure_open(self, now: float) -> str | None:
        """Open the port if it is time to try; None when open, else why not."""
        if self._client is not None and self._client.connected:
            return None
        if self._client is not None:
            self._lost("the port closed (adapter unplugged?)")
        if now < self._next_open:
            return self.last_reason or "port not open"
        s = self.settings
        client = AsyncModbusSerialClient(
            s.port,
            framer=FramerType.RTU,
            baudrate=s.baudrate,
            bytesize=8,
            parity=s.parity,
            stopbits=s.stopbits,
            timeout=s.timeout_s,
            retries=s.retries,
            reconnect_delay=0,  # reopening is ours: pymodbus's would hide the loss
            trace_packet=self._trace,
        )
        try:
            opened = await client.connect()
        except Exception as exc:  # pyserial raises whatever the OS said
            opened, reason = False, f"{type(exc).__name__}: {exc}"
        else:
            reason = f"cannot open {s.port}"
        if not opened:
            client.close()
            self._schedule_reopen(now)
            if reason != self.last_reason:
                _log.warning("sonde port not open; retrying", port=s.port, reason=reason)
            self.last_reason = reason
            return reason
        self._client = client
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
        client, self._client = self._client, None
        if client is not None:
            client.close()
        if self.up:
            self.losses += 1
            _log.warning("sonde port lost; reopening", port=self.settings.port, reason=reason)
        self.up = False
        self.last_reason = reason
        self._schedule_reopen(self._monotonic())

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if sending:
            self._rx_bytes = 0
            self.requests += 1
        else:
            self._rx_bytes += len(data)
        return data

    async def close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            client.close()
        self.up = False

    # ------------------------------------------------------------ a sample

    async def read(self) -> SondeReading:
        """Every parameter now, or why not. Never raises for a sonde or port fault."""
        start = self._monotonic()
        wall = self._wall()
        requests_before = self.requests
        values: dict[str, float | None] = dict.fromkeys(self.names)
        missing: dict[str, str] = {}
        status, error = OK, None
        why_closed = await self._ensure_open(start)
        if why_closed is not None:
            status, error = DISCONNECTED, why_closed
            missing = dict.fromkeys(self.names, DISCONNECTED)
        else:
            for block in self.blocks:
                got, failure = await self._read_block(block)
                if failure is not None:
                    status, error = failure
                    missing.update((p.name, status) for p in block.parameters)
                    continue
                values.update(got)
        for name, value in values.items():
            if value is None and name not in missing:
                missing[name] = "nan"
        if status == OK and missing:
            status = PARTIAL
        if status != self.last_reason and status in (OK, PARTIAL) and self.last_reason:
            _log.info("sonde answering again", after=self.last_reason)
        if status in (OK, PARTIAL):
            self.last_reason = None
        elif status not in (DISCONNECTED, self.last_reason):
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
        )

    async def _read_block(
        self, block: Block
    ) -> tuple[dict[str, float | None], tuple[str, str] | None]:
        from cc_daemon.drivers.sonde.registers import decode

        client = self._client
        assert client is not None
        self._rx_bytes = 0
        try:
            response = await client.read_holding_registers(
                block.address, count=block.count, device_id=self.settings.slave_id
            )
        except ConnectionException as exc:
            self._lost(str(exc))
            return {}, (DISCONNECTED, str(exc))
        except ModbusException as exc:
            if not client.connected:
                self._lost(str(exc))
                return {}, (DISCONNECTED, str(exc))
            if self._rx_bytes:
                return {}, (CRC, f"{self._rx_bytes} bytes but no valid reply (bad CRC?)")
            return {}, (TIMEOUT, f"no reply in {self.settings.timeout_s:g} s")
        except OSError as exc:
            self._lost(f"{type(exc).__name__}: {exc}")
            return {}, (DISCONNECTED, str(exc))
        if isinstance(response, ExceptionResponse) or response.isError():
            code = getattr(response, "exception_code", None)
            return {}, (EXCEPTION, f"exception response code {code}")
        if len(response.registers) != block.count:
            return {}, (CRC, f"{len(response.registers)} registers, wanted {block.count}")
        return decode(block, response.registers), None
