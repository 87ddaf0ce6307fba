"""Frame layouts: the one place that knows each frame's bytes.

    sync(1) type(1) timestamp(2) payload(0..19) checksum(2)

Big-endian numbers; signed fields are a sign byte (00 / 01) plus a big-endian
magnitude, never two's complement; the checksum is the sum of every preceding
byte modulo 65536, most significant byte first. Altitude is decoded as sign +
3-byte magnitude because the deployed firmware encodes it that way (identical
bytes for every value the manual allows). See `docs/firmware.md`.

`M` has two lengths: the manual's 25 bytes, and the deployed 2023 firmware's
26 (a measuring-mode byte at offset 23, the checksum over bytes 0-23 at
24-25). Its layout carries both readings; the parser picks the one whose
checksum holds.

This module is pure: `encode` builds bytes from a message, the `decode_*`
functions build a message from a complete, checksum-verified frame inside a
buffer and raise `FrameError("bad_field", ...)` on an invalid field.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from enum import IntEnum

from cc_daemon.core.errors import FrameError
from cc_daemon.core.protocol.messages import (
    CONFIDENCE_MAX,
    DEPTH_MM_WIRE_MAX,
    LAT_E7_MAX,
    LON_E7_MAX,
    TIMESTAMP_WIRE_MOD,
    Ack,
    DepthReport,
    FaultReport,
    Finished,
    Message,
    ProbeDown,
    ProbePosition,
    ProbePositionRequest,
    ProbeUp,
    StartMeasuring,
    Telemetry,
)


class Sync(IntEnum):
    """First byte of a frame: who sent it."""

    AUTOPILOT = 0x50  # "P", Paparazzi
    CC = 0x52  # "R", Raspberry Pi


class AutopilotType(IntEnum):
    """Second byte of a `P` frame. With the sync byte it fixes the frame's length."""

    TELEMETRY = 0x54  # "T"
    START_MEASURING = 0x4D  # "M"
    START_MEASURING_G = 0x47  # "G": one firmware revision's start-measuring byte
    PROBE_REQUEST = 0x53  # "S"
    PROBE_UP = 0x55  # "U": RC stick up (firmware 7ab06076 on)
    PROBE_DOWN = 0x44  # "D": RC stick down


class CcType(IntEnum):
    """Second byte of an `R` frame. (Two enums: `M` means different things per side.)"""

    ACK = 0x4F  # "O"
    DEPTH = 0x4D  # "M"
    FINISHED = 0x46  # "F"
    PROBE_POSITION = 0x50  # "P"
    FAULT = 0x4C  # "L": the firmware's error report; we send it while stranded


MIN_FRAME_LENGTH = 6
MAX_FRAME_LENGTH = 26  # the firmware's start-measuring frame

# Layouts without the trailing checksum (verified separately, before decoding).
# Position frames: sync, type, time, lon sign+mag, lat sign+mag,
# alt sign + high byte + low 16 bits, sonar u32, confidence.
POSITION = struct.Struct(">BBHBIBIBBHIB")
TIMESTAMP_ONLY = struct.Struct(">BBH")
WITH_DEPTH = struct.Struct(">BBHH")
CHECKSUM = struct.Struct(">H")

POSITION_LENGTH = POSITION.size + 2  # 25
START_WITH_MODE_LENGTH = POSITION_LENGTH + 1  # 26: the firmware's P-M
TIMESTAMP_ONLY_LENGTH = TIMESTAMP_ONLY.size + 2  # 6
WITH_DEPTH_LENGTH = WITH_DEPTH.size + 2  # 8


def checksum(data: bytes | bytearray | memoryview) -> int:
    """The protocol checksum of `data`: the sum of its bytes modulo 65536."""
    return sum(data) & 0xFFFF


def _with_checksum(body: bytes) -> bytes:
    return body + CHECKSUM.pack(sum(body) & 0xFFFF)


def _sign_magnitude(value: int) -> tuple[int, int]:
    return (1, -value) if value < 0 else (0, value)


# ---------------------------------------------------------------- encoding


def _encode_position(
    message: Telemetry | StartMeasuring, type_byte: int, mode: int | None = None
) -> bytes:
    lon_sign, lon = _sign_magnitude(message.lon_e7)
    lat_sign, lat = _sign_magnitude(message.lat_e7)
    alt_sign, alt = _sign_magnitude(message.alt_mm)
    body = POSITION.pack(
        Sync.AUTOPILOT,
        type_byte,
        message.timestamp_s % TIMESTAMP_WIRE_MOD,
        lon_sign,
        lon,
        lat_sign,
        lat,
        alt_sign,
        alt >> 16,
        alt & 0xFFFF,
        message.sonar_distance_mm,
        message.sonar_confidence_pct,
    )
    return _with_checksum(body if mode is None else body + bytes((mode,)))


def _encode_timestamp_only(sync: int, type_byte: int, timestamp_s: int) -> bytes:
    return _with_checksum(TIMESTAMP_ONLY.pack(sync, type_byte, timestamp_s % TIMESTAMP_WIRE_MOD))


def _encode_depth(type_byte: int, timestamp_s: int, depth_mm: int) -> bytes:
    return _with_checksum(
        WITH_DEPTH.pack(
            Sync.CC,
            type_byte,
            timestamp_s % TIMESTAMP_WIRE_MOD,
            min(depth_mm, DEPTH_MM_WIRE_MAX),  # saturates, never wraps
        )
    )


def encode(message: Message, *, start_type: int = AutopilotType.START_MEASURING) -> bytes:
    """The frame for `message`. `start_type` lets a test or simulator send `G`."""
    match message:
        case Telemetry():
            return _encode_position(message, AutopilotType.TELEMETRY)
        case StartMeasuring():
            # A mode byte makes it the firmware's 26-byte frame.
            return _encode_position(message, start_type, message.mode)
        case ProbePositionRequest():
            return _encode_timestamp_only(Sync.AUTOPILOT, AutopilotType.PROBE_REQUEST, message[0])
        case ProbeUp():
            return _encode_timestamp_only(Sync.AUTOPILOT, AutopilotType.PROBE_UP, message[0])
        case ProbeDown():
            return _encode_timestamp_only(Sync.AUTOPILOT, AutopilotType.PROBE_DOWN, message[0])
        case Ack():
            return _encode_timestamp_only(Sync.CC, CcType.ACK, message[0])
        case DepthReport():
            return _encode_depth(CcType.DEPTH, message[0], message[1])
        case Finished():
            return _encode_depth(CcType.FINISHED, message[0], message[1])
        case ProbePosition():
            return _encode_depth(CcType.PROBE_POSITION, message[0], message[1])
        case FaultReport():
            return _encode_depth(CcType.FAULT, message[0], message[1])
    raise TypeError(f"not a protocol message: {message!r}")


# ---------------------------------------------------------------- decoding

# A decoder takes the buffer and the frame's start, and returns the message.
Decoder = Callable[[bytes | bytearray, int], Message]

_new = tuple.__new__  # the parser validated the fields; skip the per-field checks


def _position_decoder(cls: type[Telemetry]) -> Decoder:
    unpack_from = POSITION.unpack_from

    def decode(buf: bytes | bytearray, start: int) -> Message:
        (_, _, ts, lon_s, lon, lat_s, lat, alt_s, alt_hi, alt_lo, sonar, conf) = unpack_from(
            buf, start
        )
        if lon_s > 1 or lat_s > 1 or alt_s > 1 or lon > LON_E7_MAX or lat > LAT_E7_MAX:
            raise FrameError("bad_field", _position_problem(lon_s, lon, lat_s, lat, alt_s))
        if conf > CONFIDENCE_MAX:
            raise FrameError("bad_field", f"sonar_confidence_pct={conf} is over 100")
        alt = alt_hi << 16 | alt_lo
        return _new(
            cls,
            (
                ts,
                -lon if lon_s else lon,
                -lat if lat_s else lat,
                -alt if alt_s else alt,
                sonar,
                conf,
            ),
        )

    return decode


def _position_problem(lon_s: int, lon: int, lat_s: int, lat: int, alt_s: int) -> str:
    for name, sign in (("lon_e7", lon_s), ("lat_e7", lat_s), ("alt_mm", alt_s)):
        if sign > 1:
            return f"{name} sign byte is 0x{sign:02X}, not 00 or 01"
    if lon > LON_E7_MAX:
        return f"lon_e7 magnitude {lon} is beyond 180 degrees"
    return f"lat_e7 magnitude {lat} is beyond 90 degrees"


def _start_decoders() -> tuple[Decoder, Decoder]:
    """`P-M` read as 25 bytes (no mode) and as the firmware's 26 (mode at 23).

    Both reuse the telemetry decoder, so `T`, the frame that matters for
    speed, pays nothing for `M`'s second length.
    """
    position = _position_decoder(Telemetry)

    def decode_25(buf: bytes | bytearray, start: int) -> Message:
        return _new(StartMeasuring, (*position(buf, start), None))

    def decode_26(buf: bytes | bytearray, start: int) -> Message:
        return _new(StartMeasuring, (*position(buf, start), buf[start + 23]))

    return decode_25, decode_26


_DECODE_M_25, _DECODE_M_26 = _start_decoders()


def _timestamp_decoder(
    cls: type[ProbePositionRequest] | type[ProbeUp] | type[ProbeDown] | type[Ack],
) -> Decoder:
    def decode(buf: bytes | bytearray, start: int) -> Message:
        return _new(cls, (buf[start + 2] << 8 | buf[start + 3],))

    return decode


def _depth_decoder(
    cls: type[DepthReport] | type[Finished] | type[ProbePosition] | type[FaultReport],
) -> Decoder:
    def decode(buf: bytes | bytearray, start: int) -> Message:
        return _new(
            cls, (buf[start + 2] << 8 | buf[start + 3], buf[start + 4] << 8 | buf[start + 5])
        )

    return decode


class Layout:
    """How to recognise and decode one (sync, type) pair.

    `longer` is a second reading one byte longer, tried when the checksum of
    the first fails (only the firmware's 26-byte `P-M` has one).
    """

    __slots__ = ("decode", "length", "longer", "name")

    def __init__(
        self, name: str, length: int, decode: Decoder, longer: Decoder | None = None
    ) -> None:
        self.name = name
        self.length = length
        self.decode = decode
        self.longer = longer


def _key(sync: int, type_byte: int) -> int:
    return sync << 8 | type_byte


AUTOPILOT_LAYOUTS: dict[int, Layout] = {
    _key(Sync.AUTOPILOT, AutopilotType.TELEMETRY): Layout(
        "P-T", POSITION_LENGTH, _position_decoder(Telemetry)
    ),
    _key(Sync.AUTOPILOT, AutopilotType.START_MEASURING): Layout(
        "P-M", POSITION_LENGTH, _DECODE_M_25, _DECODE_M_26
    ),
    _key(Sync.AUTOPILOT, AutopilotType.PROBE_REQUEST): Layout(
        "P-S", TIMESTAMP_ONLY_LENGTH, _timestamp_decoder(ProbePositionRequest)
    ),
    _key(Sync.AUTOPILOT, AutopilotType.PROBE_UP): Layout(
        "P-U", TIMESTAMP_ONLY_LENGTH, _timestamp_decoder(ProbeUp)
    ),
    _key(Sync.AUTOPILOT, AutopilotType.PROBE_DOWN): Layout(
        "P-D", TIMESTAMP_ONLY_LENGTH, _timestamp_decoder(ProbeDown)
    ),
}

G_ALIAS_LAYOUT: dict[int, Layout] = {
    _key(Sync.AUTOPILOT, AutopilotType.START_MEASURING_G): Layout(
        "P-G", POSITION_LENGTH, _DECODE_M_25
    ),
}

CC_LAYOUTS: dict[int, Layout] = {
    _key(Sync.CC, CcType.ACK): Layout("R-O", TIMESTAMP_ONLY_LENGTH, _timestamp_decoder(Ack)),
    _key(Sync.CC, CcType.DEPTH): Layout("R-M", WITH_DEPTH_LENGTH, _depth_decoder(DepthReport)),
    _key(Sync.CC, CcType.FINISHED): Layout("R-F", WITH_DEPTH_LENGTH, _depth_decoder(Finished)),
    _key(Sync.CC, CcType.PROBE_POSITION): Layout(
        "R-P", WITH_DEPTH_LENGTH, _depth_decoder(ProbePosition)
    ),
    _key(Sync.CC, CcType.FAULT): Layout("R-L", WITH_DEPTH_LENGTH, _depth_decoder(FaultReport)),
}
