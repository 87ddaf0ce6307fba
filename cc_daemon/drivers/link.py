"""The serial link to the autopilot: open, read, write, reopen. Bytes only.

One `SerialLink` owns the UART. It hands every chunk read to `on_data` (the
caller's parser) and writes whole frames with a single `write` call each, so
frames never interleave. When the port fails or disappears (USB adapter
unplugged, EIO, device node gone) it says so through `on_state`, and reopens
the same path with capped, jittered exponential backoff for as long as it
takes; while it cannot, it says so again at a slowing interval ("still waiting
for /dev/ttyUSB7: 14 attempts since 10:02:11", see `waiting.py`) in the log and
through `on_waiting`. Nothing written while the link is down is queued: `write` returns
False and the frame is dropped (a depth report from a second ago is no use).

It never parses, never decides anything about casts, and never lets a
callback's exception escape into the event loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import random
import time
from collections.abc import Callable
from typing import Any

import structlog

from cc_daemon.drivers import fdserial
from cc_daemon.ground.waiting import WaitReport

_log = structlog.get_logger("cc_daemon.link")


def _identity(protocol: _LinkProtocol) -> _LinkProtocol:
    return protocol


class _LinkProtocol(asyncio.Protocol):
    def __init__(self, link: SerialLink) -> None:
        self._link = link
        self.lost: asyncio.Future[BaseException | None] = asyncio.get_running_loop().create_future()

    def data_received(self, data: bytes) -> None:
        try:
            self._link.on_data(data)
        except Exception:  # a handler bug must not take the port down
            _log.exception("error handling received bytes")

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.lost.done():
            self.lost.set_result(exc)


class SerialLink:
    def __init__(
        self,
        port: str,
        *,
        on_data: Callable[[bytes], None],
        on_state: Callable[[bool, str], None] | None = None,
        baudrate: int = 9600,
        bytesize: int = 8,
        parity: str = "N",
        stopbits: float = 1,
        exclusive: bool = True,
        reconnect_initial_s: float = 0.2,
        reconnect_max_s: float = 5.0,
        jitter: Callable[[], float] = random.random,
        on_waiting: Callable[[str], None] | None = None,
        wait_report: WaitReport | None = None,
    ) -> None:
        self.port = port
        self.on_data = on_data
        self.on_state = on_state
        self.on_waiting = on_waiting
        self.waiting = wait_report or WaitReport()
        self._serial_kwargs: dict[str, Any] = {
            "baudrate": baudrate,
            "bytesize": bytesize,
            "parity": parity,
            "stopbits": stopbits,
            "exclusive": exclusive,
        }
        self.reconnect_initial_s = reconnect_initial_s
        self.reconnect_max_s = reconnect_max_s
        self._jitter = jitter
        self._transport: asyncio.BaseTransport | None = None
        self.bytes_written = 0
        self.frames_dropped = 0  # writes refused because the link was down
        self.opens = 0

    @property
    def up(self) -> bool:
        transport = self._transport
        return transport is not None and not transport.is_closing()

    def write(self, frame: bytes) -> bool:
        """Send one whole frame now; False (and nothing queued) if the link is down."""
        transport = self._transport
        if transport is None or transport.is_closing():
            self.frames_dropped += 1
            return False
        transport.write(frame)  # type: ignore[attr-defined]
        self.bytes_written += len(frame)
        return True

    def backoff_delay(self, failures: int) -> float:
        """Delay before reopen attempt number `failures` (1-based): capped, jittered."""
        ceiling = min(self.reconnect_max_s, self.reconnect_initial_s * 2.0 ** (failures - 1))
        # Jitter between 75 % and 100 % of the ceiling keeps two daemons (or a
        # daemon and a udev rule) from retrying in lock-step, and never exceeds the cap.
        return ceiling * (0.75 + 0.25 * self._jitter())

    async def run(self) -> None:
        """Keep the port open until cancelled. Never returns otherwise."""
        loop = asyncio.get_running_loop()
        failures = 0
        last_error = ""
        while True:
            protocol = _LinkProtocol(self)
            try:
                transport, _ = await fdserial.create_serial_connection(
                    loop, functools.partial(_identity, protocol), self.port, **self._serial_kwargs
                )
            except Exception as exc:
                # pyserial raises SerialException, OSError, ValueError and, from
                # termios on a failing adapter, termios.error: none may end the link.
                failures += 1
                error = f"{type(exc).__name__}: {exc}" + _held_by(self.port, exc)
                due = self.waiting.failed(loop.time(), time.time())
                if error != last_error:  # say each new reason once; the retries are expected
                    _log.warning("cannot open serial port", port=self.port, error=error)
                    last_error = error
                elif due:  # and say again, ever less often, that we are still at it
                    self._say_waiting(error)
                await asyncio.sleep(self.backoff_delay(failures))
                continue
            self._transport = transport
            self.opens += 1
            self.waiting.reset()
            opened_at = loop.time()
            last_error = ""
            _log.info("serial port open", port=self.port, **self._serial_kwargs)
            self._notify(True, "open")
            try:
                lost_with = await protocol.lost
            except asyncio.CancelledError:
                self._transport = None
                transport.close()
                # Let the transport finish closing the port before we go.
                with contextlib.suppress(asyncio.CancelledError, TimeoutError):
                    await asyncio.wait_for(asyncio.shield(protocol.lost), 1.0)
                raise
            self._transport = None
            reason = str(lost_with) if lost_with else "closed"
            _log.warning("serial port lost", port=self.port, reason=reason)
            self._notify(False, reason)
            # A port that stayed up a while starts again from the shortest delay;
            # one that drops as soon as it opens (a flapping adapter) keeps backing off.
            stable = loop.time() - opened_at >= self.reconnect_max_s
            failures = 1 if stable else failures + 1
            await asyncio.sleep(self.backoff_delay(failures))

    def _say_waiting(self, error: str) -> None:
        text = self.waiting.message(self.port)
        if " (held by " in error:  # a second daemon, minicom...: say who, every time
            text += error[error.index(" (held by ") :]
        _log.warning(text, port=self.port, attempts=self.waiting.attempts, error=error)
        if self.on_waiting is None:
            return
        try:
            self.on_waiting(text)
        except Exception:
            _log.exception("error handling a still-waiting report")

    def _notify(self, up: bool, reason: str) -> None:
        if self.on_state is None:
            return
        try:
            self.on_state(up, reason)
        except Exception:
            _log.exception("error handling link state change")


def _held_by(port: str, exc: Exception) -> str:
    """` (held by pid 20329 (cc-daemon))` when the port is locked by another process."""
    if "lock" not in str(exc).lower() and getattr(exc, "errno", None) not in (
        errno.EBUSY,
        errno.EAGAIN,
    ):
        return ""
    from cc_daemon.ground.portusers import port_users  # only for a port held by another

    users = port_users(port)
    return f" (held by {', '.join(str(u) for u in users)})" if users else ""
