"""A simulated Blue Robotics Ping1D: the ping protocol at 115200 8N1, readings from the lake.

This module owns the device side of the sonar link:
- `FieldSounder`: what a Ping1D hears over the simulated water-depth field:
  the depth plus noise, a confidence that drops in shallow water (under
  `SHALLOW_M`), on steep bottoms and under way, and dropouts under way
  (propeller wash: distance 0, confidence 0, as a real Ping reports a lost echo).
- `Ping1DDevice` (sans-IO): answers every message a Ping1D answers, in brping's
  table (`ping.PING1D_TABLE`): a request (general_request, or the legacy form:
  the id with no payload) for device_information (4), protocol_version (5) or
  any Ping1D value (1200-1215: firmware_version, device_id, voltage_5,
  speed_of_sound, range, mode_auto, ping_interval, gain_setting,
  transmit_duration, general_info, distance_simple, distance, temperatures,
  ping_enable; 1300 profile; 1301 oss_profile_configuration) is answered from
  its settings and the sounder; every set command (100, 1000-1007) is kept and
  acknowledged (ack, 1), so brping reads back what it set; goto_bootloader gets
  no answer (a real Ping leaves the protocol); anything else is NACKed. It
  streams distance_simple every `interval_s` between continuous_start (1400)
  and continuous_stop (1401).
- `Ping1DServer`: the device on a file descriptor (a pty's master end) or a
  serial port (`cc-daemon simulate-sonar --port PATH`).

Replies and the stream are built with brping's Ping1D message table. The device
never reads a clock itself (the server passes `now`) and never looks inside
whoever reads it.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import serial_asyncio

from cc_daemon.drivers.sonar import ping
from cc_daemon.drivers.sonar.ping import (
    ContinuousStart,
    ContinuousStop,
    GeneralRequest,
    OtherMessage,
    PingStream,
)
from cc_daemon.sim import echosounder
from cc_daemon.sim.echosounder import EchoErrors, EchoKind
from cc_daemon.sim.mission import Mission, Point

STREAM_INTERVAL_S = 0.25  # the manual: distance_simple every 250 ms
SPEED_OF_SOUND_MM_S = 1_500_000  # fresh water, as a Ping1D ships
ACK = 1
GOTO_BOOTLOADER = 1100
# The set commands and the value each sets (the same field names as the gets).
_SETS = {100, 1000, 1001, 1002, 1003, 1004, 1005, 1006, 1007}
# What the simulated Ping reports before anything is set: a Ping1D (device type
# 1) at 5 V, auto mode, pinging every 100 ms, over 0-30 m.
_DEFAULTS: dict[str, int] = {
    "device_type": 1,
    "device_revision": 1,
    "device_model": 1,
    "firmware_version_major": 3,
    "firmware_version_minor": 28,
    "firmware_version_patch": 0,
    "reserved": 0,
    "voltage_5": 5000,
    "speed_of_sound": SPEED_OF_SOUND_MM_S,
    "scan_start": 0,
    "scan_length": 30_000,
    "mode_auto": 1,
    "ping_interval": 100,
    "gain_setting": 3,
    "transmit_duration": 100,
    "processor_temperature": 3500,
    "pcb_temperature": 3000,
    "ping_enabled": 1,
    "number_of_points": 200,
    "normalization_enabled": 1,
    "enhance_enabled": 0,
}
_ECHO_MESSAGES = (ping.DISTANCE_SIMPLE, 1212, 1300)  # those carrying a fresh echo
PROTOCOL_VERSION = (1, 0, 0)
SHALLOW_M = 1.5  # below this the echo crowds the transmit pulse
_SHALLOW_PENALTY_PER_M = 12.0  # 0.6 m of water costs about 11 %
_STEEP_PENALTY_PER_SLOPE = 200.0  # a 0.1 m/m slope costs 20 % confidence
_SLOPE_STEP_M = 2.0


@dataclass(frozen=True, slots=True)
class Echo:
    distance_mm: int
    confidence_pct: int


class FieldSounder:
    """What the simulated Ping hears at the boat's position. Seeded: reproducible.

    `where()` gives the boat's position and whether it is under way.
    """

    def __init__(
        self,
        mission: Mission,
        where: Callable[[], tuple[Point, bool]],
        *,
        seed: int = 1,
        dropout_rate: float = 0.03,
        noise_m: float = 0.02,
        errors: EchoErrors | None = None,
        draft_m: float = 0.0,
    ) -> None:
        """`errors`: how it errs under way (`sim.echosounder`); by default a 3 % share of
        outliers beside the dropouts (`dropout_rate`) and the noise (`noise_m`).
        `draft_m`: how deep the transducer sits (it reads the bed that much nearer)."""
        if not 0.0 <= dropout_rate <= 1.0:
            raise ValueError(f"dropout_rate={dropout_rate} is invalid: allowed 0..1")
        self.mission = mission
        self.where = where
        self.dropout_rate = dropout_rate
        self.noise_m = noise_m
        self.errors = errors or EchoErrors(dropout_rate=dropout_rate, noise_m=noise_m)
        self._rng = random.Random(seed)
        self.dropouts = 0
        self.outliers = 0
        self.last_kind = EchoKind.GOOD  # what the last reading was (the truth, for tests)
        self._readings = 0  # its clock for the heave: one reading per stream interval
        self.draft_m = draft_m

    def slope(self, p: Point) -> float:
        """The bottom's slope at `p`, metres per metre (central differences)."""
        depth = self.mission.field.depth_at
        h = _SLOPE_STEP_M
        de = depth(Point(p.east_m + h, p.north_m)) - depth(Point(p.east_m - h, p.north_m))
        dn = depth(Point(p.east_m, p.north_m + h)) - depth(Point(p.east_m, p.north_m - h))
        return math.hypot(de, dn) / (2 * h)

    def __call__(self) -> Echo:
        point, moving = self.where()
        rng = self._rng
        self._readings += 1
        depth = self.mission.field.depth_at(point) - self.draft_m
        if moving:
            confidence = rng.randint(75, 90) - self._penalty(point, depth)
            t_s = self._readings * STREAM_INTERVAL_S
            reading = echosounder.read(depth, confidence, t_s, rng, self.errors)
            self.last_kind = reading.kind
            self.dropouts += reading.kind is EchoKind.DROPOUT
            self.outliers += reading.kind.outlier
            return Echo(round(reading.distance_m * 1000), reading.confidence_pct)
        self.last_kind = EchoKind.GOOD
        noise = max(-3 * self.noise_m, min(3 * self.noise_m, rng.gauss(0.0, self.noise_m)))
        confidence = float(rng.randint(92, 100)) - self._penalty(point, depth)
        return Echo(round(max(depth + noise, 0.0) * 1000), max(0, min(100, round(confidence))))

    def _penalty(self, point: Point, depth: float) -> float:
        """What shallow water and a steep bed take off a good echo's confidence."""
        shallow = max(0.0, SHALLOW_M - depth) * _SHALLOW_PENALTY_PER_M
        return shallow + min(40.0, self.slope(point) * _STEEP_PENALTY_PER_SLOPE)


class Ping1DDevice:
    """The Ping1D's protocol behaviour; see the module docstring. `now` never goes backwards."""

    def __init__(
        self,
        sounder: Callable[[], Echo],
        *,
        device_id: int = 1,
        interval_s: float = STREAM_INTERVAL_S,
    ) -> None:
        if interval_s <= 0:
            raise ValueError(f"interval_s={interval_s} is invalid: allowed > 0")
        self.sounder = sounder
        self.device_id = device_id
        self.interval_s = interval_s
        self._stream = PingStream()
        self.streaming = False
        self._next_at = math.inf
        self.settings = dict(_DEFAULTS)
        self.ping_number = 0
        self.requests: list[int] = []  # every request's message id (general requests: the asked id)
        self.sent_readings = 0

    @property
    def bad_frames(self) -> int:
        return self._stream.errors

    @property
    def next_deadline(self) -> float:
        """When `poll` next has a reading to stream (inf when not streaming)."""
        return self._next_at

    def receive(self, now: float, data: bytes) -> bytes:
        """Bytes from the host; the replies to write back."""
        out = bytearray()
        for envelope in self._stream.feed(data):
            event = envelope.event
            to = envelope.src
            if isinstance(event, GeneralRequest):
                self.requests.append(event.requested_id)
                out += self._answer(event.requested_id, to)
            elif isinstance(event, ContinuousStart | ContinuousStop):
                self.requests.append(
                    ping.CONTINUOUS_START
                    if isinstance(event, ContinuousStart)
                    else ping.CONTINUOUS_STOP
                )
                if event.requested_id != ping.DISTANCE_SIMPLE:
                    out += self._nack(event.requested_id, "only distance_simple streams", to)
                elif isinstance(event, ContinuousStart):
                    if not self.streaming:
                        self.streaming = True
                        self._next_at = now + self.interval_s
                else:
                    self.streaming = False
                    self._next_at = math.inf
            elif isinstance(event, OtherMessage):
                self.requests.append(event.message_id)
                out += self._other(event, to)
        return bytes(out)

    def _other(self, event: OtherMessage, to: int) -> bytes:
        mid = event.message_id
        if mid in _SETS:
            for name, value in event.fields:
                self.settings[name] = value
            if "device_id" in dict(event.fields):
                self.device_id = event.field("device_id")
            return ping.encode(ACK, src=self.device_id, dst=to, acked_id=mid)
        if mid in (ACK, ping.NACK, GOTO_BOOTLOADER) or mid == 3:  # 3: ascii_text
            return b""  # nothing a Ping answers (the bootloader leaves the protocol)
        return self._nack(mid, "not a request", to)

    def poll(self, now: float) -> bytes:
        """The streamed reading due at `now`, if any (never a burst of catch-up)."""
        if not self.streaming or now < self._next_at:
            return b""
        self._next_at += self.interval_s
        if self._next_at <= now:
            self._next_at = now + self.interval_s
        return self._distance(0)

    def _answer(self, requested: int, to: int) -> bytes:
        me = self.device_id
        if requested == ping.PROTOCOL_VERSION:
            major, minor, patch = PROTOCOL_VERSION
            return ping.encode(
                requested,
                src=me,
                dst=to,
                version_major=major,
                version_minor=minor,
                version_patch=patch,
            )
        if requested == ping.DEVICE_ID:
            return ping.encode(requested, src=me, dst=to, device_id=me)
        if requested == ping.SPEED_OF_SOUND:
            sos = self.settings["speed_of_sound"]
            return ping.encode(requested, src=me, dst=to, speed_of_sound=sos)
        if requested == ping.DISTANCE_SIMPLE:
            return self._distance(to)
        spec = ping.PING1D_TABLE.get(requested)
        if spec is None or requested in _SETS or not 4 <= requested < 1400 or requested == 6:
            return self._nack(requested, "not a value this device reports", to)
        if requested == GOTO_BOOTLOADER:
            return b""
        values: dict[str, int | bytes] = {"device_id": me, **self.settings}
        if requested in _ECHO_MESSAGES:
            echo = self.sounder()
            self.ping_number += 1
            values |= {
                "distance": echo.distance_mm,
                "confidence": echo.confidence_pct,
                "ping_number": self.ping_number,
            }
        if requested == 1300:  # a flat profile: the points, no echo shape simulated
            points = self.settings["number_of_points"]
            values |= {"profile_data_length": points, "profile_data": bytes(points)}
        fields = {n: values[n] for n in spec["field_names"] if n in values}
        return ping.encode(requested, src=me, dst=to, **fields)

    def _distance(self, to: int) -> bytes:
        echo = self.sounder()
        self.sent_readings += 1
        return ping.encode(
            ping.DISTANCE_SIMPLE,
            src=self.device_id,
            dst=to,
            distance=echo.distance_mm,
            confidence=echo.confidence_pct,
        )

    def _nack(self, nacked: int, why: str, to: int) -> bytes:
        return ping.encode(
            ping.NACK, src=self.device_id, dst=to, nacked_id=nacked, nack_message=why.encode()
        )


class Ping1DServer:
    """Runs a `Ping1DDevice` on a descriptor or a serial port until `close()`.

    Times given to the device are the event loop's clock.
    """

    def __init__(self, device: Ping1DDevice) -> None:
        self.device = device
        self._loop = asyncio.get_running_loop()
        self._fd = -1
        self._transport: Any = None  # pyserial-asyncio's SerialTransport (untyped)
        self._task: asyncio.Task[None] | None = None
        self.bytes_in = 0
        self.bytes_out = 0
        self.hung_up = False

    @classmethod
    async def over_fd(cls, fd: int, device: Ping1DDevice) -> Ping1DServer:
        """On a descriptor we do not own (a pty's master end; never closed here)."""
        server = cls(device)
        os.set_blocking(fd, False)
        server._fd = fd
        server._loop.add_reader(fd, server._read_ready)
        server._start()
        return server

    @classmethod
    async def over_serial(cls, path: str, device: Ping1DDevice) -> Ping1DServer:
        """On a serial port at 115200 8N1, as a Ping1D."""
        server = cls(device)
        transport, _ = await serial_asyncio.create_serial_connection(
            server._loop, lambda: _DeviceProtocol(server), path, baudrate=115200
        )
        server._transport = transport
        server._start()
        return server

    def _start(self) -> None:
        self._task = self._loop.create_task(self._stream(), name="ping1d-stream")

    async def _stream(self) -> None:
        device = self.device
        while True:
            deadline = device.next_deadline
            delay = deadline - self._loop.time() if deadline != math.inf else STREAM_INTERVAL_S
            await asyncio.sleep(max(delay, 0.0))
            self.write(device.poll(self._loop.time()))

    def data_received(self, data: bytes) -> None:
        self.bytes_in += len(data)
        self.write(self.device.receive(self._loop.time(), data))

    def write(self, data: bytes) -> None:
        if not data:
            return
        if self._transport is not None:
            self._transport.write(data)
        elif self._fd >= 0:
            try:
                os.write(self._fd, data)
            except BlockingIOError:
                return  # nobody reads the other end: a real UART drops the bytes too
            except OSError:
                self._hang_up()
                return
        else:
            return
        self.bytes_out += len(data)

    def _read_ready(self) -> None:
        try:
            data = os.read(self._fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._hang_up()
            return
        self.data_received(data)

    def _hang_up(self) -> None:
        self.hung_up = True
        if self._fd >= 0:
            self._loop.remove_reader(self._fd)
            self._fd = -1

    async def close(self) -> None:
        """Stop streaming and let go of the descriptor or port. Safe to call twice."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._hang_up()
        transport, self._transport = self._transport, None
        if transport is not None:
            transport.close()


class _DeviceProtocol(asyncio.Protocol):
    def __init__(self, server: Ping1DServer) -> None:
        self._server = server

    def data_received(self, data: bytes) -> None:
        self._server.data_received(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self._server.hung_up = True
