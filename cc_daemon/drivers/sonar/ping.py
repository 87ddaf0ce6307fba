"""The Ping1D's side of Blue Robotics' ping protocol, over `brping`: bytes in, events out.

This module owns the glue between the wire and the rest of cc-daemon: the
Ping1D message table (brping's default table maps id 1211 to the S500's
`altitude`, so a Ping1D `distance_simple` decoded with it has no `distance`
or `confidence`), encoding a message with brping, and `PingStream`, which
feeds bytes to brping's `PingParser` and turns what it finds into frozen
events.

`PingStream` adds what brping's parser lacks for a long-running reader:
after a bad checksum it searches for the next frame from the byte after the
failed `B` (brping resumes after the whole bad frame, and may skip a good
one); a payload length above `MAX_PAYLOAD` is dropped at once instead of
swallowing minutes of a slow stream; a `B` followed by `B` keeps the second
one; and a message outside the table is reported as `OtherMessage` without
brping printing to stdout.

It does no I/O, reads no clock, and never raises on bytes from the peer.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from brping import definitions
from brping.pingmessage import PingMessage, PingParser

from cc_daemon.core.errors import FieldError

GENERAL_REQUEST = int(definitions.COMMON_GENERAL_REQUEST)  # 6
NACK = int(definitions.COMMON_NACK)  # 2
PROTOCOL_VERSION = int(definitions.COMMON_PROTOCOL_VERSION)  # 5
DEVICE_ID = int(definitions.PING1D_DEVICE_ID)  # 1201
SPEED_OF_SOUND = int(definitions.PING1D_SPEED_OF_SOUND)  # 1203
DISTANCE_SIMPLE = int(definitions.PING1D_DISTANCE_SIMPLE)  # 1211
CONTINUOUS_START = int(definitions.PING1D_CONTINUOUS_START)  # 1400
CONTINUOUS_STOP = int(definitions.PING1D_CONTINUOUS_STOP)  # 1401

# What a Ping1D speaks: the common messages and its own, as brping's
# PingDevice builds it for a Ping1D. Never brping's payload_dict_all.
PING1D_TABLE: dict[int, dict[str, Any]] = {
    **definitions.payload_dict_common,
    **definitions.payload_dict_ping1d,
}

HEADER_LENGTH = 8
CHECKSUM_LENGTH = 2
# The Ping1D's longest message is a profile of up to a few hundred points;
# anything longer is a corrupt length field.
MAX_PAYLOAD = 1024

_B, _R = 0x42, 0x52


def encode(message_id: int, *, src: int = 0, dst: int = 0, **fields: int | bytes) -> bytes:
    """One Ping1D message, packed by brping. Raises FieldError for an unknown id or field."""
    spec = PING1D_TABLE.get(message_id)
    if spec is None:
        raise FieldError("message_id", message_id, "a Ping1D or common message id")
    names = tuple(spec["field_names"])
    unknown = sorted(set(fields) - set(names))
    if unknown:
        raise FieldError(unknown[0], fields[unknown[0]], f"a field of {spec['name']}: {names}")
    if message_id == NACK:
        return _encode_nack(src, dst, int(fields.get("nacked_id", 0)), fields.get("nack_message"))
    message = PingMessage(message_id, payload_dict=PING1D_TABLE)
    message.src_device_id = src
    message.dst_device_id = dst
    for name, value in fields.items():
        setattr(message, name, value)
    return bytes(message.pack_msg_data())


def _encode_nack(src: int, dst: int, nacked_id: int, text: int | bytes | None) -> bytes:
    # brping 0.2.5 cannot build its own text messages (PingMessage(COMMON_NACK)
    # takes len() of the int it just put in the text field): packed here.
    payload = struct.pack("<H", nacked_id) + (text if isinstance(text, bytes) else b"")
    head = struct.pack("<BBHHBB", _B, _R, len(payload), NACK, src, dst) + payload
    return head + struct.pack("<H", sum(head) & 0xFFFF)


def request(requested_id: int, *, dst: int = 1) -> bytes:
    """A general_request (id 6) for `requested_id`, from us (0) to device `dst`."""
    return encode(GENERAL_REQUEST, dst=dst, requested_id=requested_id)


# ---------------------------------------------------------------- events


@dataclass(frozen=True, slots=True)
class DistanceSimple:
    distance_mm: int
    confidence_pct: int


@dataclass(frozen=True, slots=True)
class ProtocolVersion:
    major: int
    minor: int
    patch: int


@dataclass(frozen=True, slots=True)
class DeviceId:
    device_id: int


@dataclass(frozen=True, slots=True)
class SpeedOfSound:
    mm_s: int


@dataclass(frozen=True, slots=True)
class GeneralRequest:
    requested_id: int


@dataclass(frozen=True, slots=True)
class ContinuousStart:
    requested_id: int


@dataclass(frozen=True, slots=True)
class ContinuousStop:
    requested_id: int


@dataclass(frozen=True, slots=True)
class Nack:
    nacked_id: int
    text: str


@dataclass(frozen=True, slots=True)
class OtherMessage:
    """A well-formed frame whose meaning the reader does not use; its integer fields."""

    message_id: int
    fields: tuple[tuple[str, int], ...] = ()

    def field(self, name: str, default: int = 0) -> int:
        return dict(self.fields).get(name, default)


@dataclass(frozen=True, slots=True)
class BadFrame:
    """Bytes that looked like the start of a frame and were not one."""

    reason: str
    raw: bytes


PingEvent = (
    DistanceSimple
    | ProtocolVersion
    | DeviceId
    | SpeedOfSound
    | GeneralRequest
    | ContinuousStart
    | ContinuousStop
    | Nack
    | OtherMessage
    | BadFrame
)


@dataclass(frozen=True, slots=True)
class Envelope:
    """An event with the header's source and destination device ids."""

    event: PingEvent
    src: int
    dst: int


def _brping_can_unpack(head: bytearray) -> bool:
    """Whether brping knows this frame's id and its payload is empty or long enough."""
    spec = PING1D_TABLE.get(_u16(head, 4))
    if spec is None:
        return False
    length = _u16(head, 2)
    return length == 0 or length >= spec["payload_length"]


def _checked_event(message: Any) -> PingEvent:
    mid = int(message.message_id)
    if int(message.payload_length) == 0 and PING1D_TABLE[mid]["payload_length"] > 0:
        # A message with its id and no payload is the older request form
        # (brping's Ping1D.legacyRequest): "send me this".
        return GeneralRequest(mid)
    return _event(message)


def _event(message: Any) -> PingEvent:
    mid = int(message.message_id)
    if mid == DISTANCE_SIMPLE:
        return DistanceSimple(int(message.distance), int(message.confidence))
    if mid == PROTOCOL_VERSION:
        return ProtocolVersion(
            int(message.version_major), int(message.version_minor), int(message.version_patch)
        )
    if mid == DEVICE_ID:
        return DeviceId(int(message.device_id))
    if mid == SPEED_OF_SOUND:
        return SpeedOfSound(int(message.speed_of_sound))
    if mid == GENERAL_REQUEST:
        return GeneralRequest(int(message.requested_id))
    if mid == CONTINUOUS_START:
        return ContinuousStart(int(message.id))
    if mid == CONTINUOUS_STOP:
        return ContinuousStop(int(message.id))
    if mid == NACK:
        text = bytes(getattr(message, "nack_message", b"")).rstrip(b"\0").decode("ascii", "replace")
        return Nack(int(message.nacked_id), text)
    spec = PING1D_TABLE.get(mid)
    names = spec["field_names"] if spec is not None else ()
    values = tuple(
        (name, int(value))
        for name in names
        if isinstance(value := getattr(message, name, None), int)
    )
    return OtherMessage(mid, values)


class PingStream:
    """Bytes in, `Envelope`s out; see the module docstring. Counts what it dropped."""

    def __init__(self) -> None:
        self._parser = PingParser(payload_dict=PING1D_TABLE)
        self.frames = 0
        self.errors = 0

    def feed(self, data: bytes) -> list[Envelope]:
        out: list[Envelope] = []
        parser = self._parser
        work = bytearray(data)
        i = 0
        while i < len(work):
            byte = work[i]
            i += 1
            state = parser.state
            if state == PingParser.WAIT_CHECKSUM_H and not _brping_can_unpack(parser.buf):
                # brping would print to stdout ("Unknown message", "error
                # unpacking payload"): finish this frame here.
                frame = bytes(parser.buf) + bytes([byte])
                self._reset()
                if not _checksum_ok(frame):
                    work[i:i] = self._bad("checksum", frame, out)
                elif _u16(frame, 4) in PING1D_TABLE:
                    name = PING1D_TABLE[_u16(frame, 4)]["name"]
                    reason = f"{name} payload of {_u16(frame, 2)} bytes is too short"
                    self._bad(reason, frame, out)  # a whole, checked frame: nothing to search
                else:
                    self.frames += 1
                    out.append(Envelope(OtherMessage(_u16(frame, 4)), frame[6], frame[7]))
                continue
            result = parser.parse_byte(byte)
            if state == PingParser.WAIT_HEADER and byte == _B and parser.state != state:
                parser.parse_byte(byte)  # "BBR": the second B may start the frame
            elif state == PingParser.WAIT_LENGTH_H and parser.payload_length > MAX_PAYLOAD:
                frame = bytes(parser.buf)
                self._reset()
                work[i:i] = self._bad(f"payload length {_u16(frame, 2)} too long", frame, out)
            elif result == PingParser.NEW_MESSAGE:
                message = parser.rx_msg
                self.frames += 1
                event = _checked_event(message)
                out.append(Envelope(event, int(message.src_device_id), int(message.dst_device_id)))
            elif result == PingParser.ERROR:
                frame = bytes(parser.rx_msg.msg_data)
                parser.state = PingParser.WAIT_START
                work[i:i] = self._bad("checksum", frame, out)
        return out

    def _bad(self, reason: str, frame: bytes, out: list[Envelope]) -> bytes:
        """Count and report a bad frame; the bytes after its B, to search again."""
        self.errors += 1
        out.append(Envelope(BadFrame(reason, frame), -1, -1))
        return frame[1:]

    def _reset(self) -> None:
        parser = self._parser
        parser.state = PingParser.WAIT_START
        parser.buf = bytearray()
        parser.payload_length = 0
        parser.message_id = 0


def _u16(frame: bytes | bytearray, offset: int) -> int:
    return frame[offset] | frame[offset + 1] << 8


def _checksum_ok(frame: bytes) -> bool:
    return len(frame) >= HEADER_LENGTH + CHECKSUM_LENGTH and (sum(frame[:-2]) & 0xFFFF) == _u16(
        frame, len(frame) - 2
    )
