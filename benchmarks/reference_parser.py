"""The naive reference: a byte-at-a-time state machine, as the firmware parses.

It parses the way the autopilot firmware's C code does, ported straight to
Python: wait for a sync byte, read the type byte to learn the length, collect
bytes up to that length, check the additive checksum, then decode the fields
with `int.from_bytes`. It is written to be honest, not slow: locals in the
hot loop, one dictionary lookup per frame, no per-byte function calls.

It decodes into the project's own message classes through their public,
validating constructors, so the work per frame is comparable with `Parser`.
Like the firmware, after a bad frame it goes back to waiting for a sync byte
*after* the frame, so a valid frame that starts inside a corrupt one is lost;
only its speed is compared, never its recovery.

It lives in the benchmark, not in `cc_daemon`: nothing in the daemon uses it.
"""

from __future__ import annotations

from collections.abc import Callable

from cc_daemon.core.errors import FieldError
from cc_daemon.core.protocol import (
    Ack,
    DepthReport,
    Finished,
    Message,
    ProbePosition,
    ProbePositionRequest,
    StartMeasuring,
    Telemetry,
)

WAIT_SYNC = 0
TYPE = 1
DATA = 2

_SYNC_P = 0x50
_SYNC_R = 0x52

FrameDecoder = Callable[[bytearray], Message | None]


def _no_frame(frame: bytearray) -> Message | None:
    return None


def _signed(frame: bytearray, start: int, end: int) -> int | None:
    """Sign byte + big-endian magnitude; None for a sign byte other than 00/01."""
    sign = frame[start]
    magnitude = int.from_bytes(frame[start + 1 : end], "big")
    if sign == 0:
        return magnitude
    if sign == 1:
        return -magnitude
    return None


def _position(cls: type[Telemetry] | type[StartMeasuring]) -> FrameDecoder:
    def decode(frame: bytearray) -> Message | None:
        lon = _signed(frame, 4, 9)
        lat = _signed(frame, 9, 14)
        alt = _signed(frame, 14, 18)
        if lon is None or lat is None or alt is None:
            return None
        try:
            return cls(
                int.from_bytes(frame[2:4], "big"),
                lon,
                lat,
                alt,
                int.from_bytes(frame[18:22], "big"),
                frame[22],
            )
        except FieldError:
            return None

    return decode


def _timestamp_only(cls: type[ProbePositionRequest] | type[Ack]) -> FrameDecoder:
    def decode(frame: bytearray) -> Message | None:
        return cls(int.from_bytes(frame[2:4], "big"))

    return decode


def _with_depth(cls: type[DepthReport] | type[Finished] | type[ProbePosition]) -> FrameDecoder:
    def decode(frame: bytearray) -> Message | None:
        return cls(int.from_bytes(frame[2:4], "big"), int.from_bytes(frame[4:6], "big"))

    return decode


# (sync << 8 | type) -> (frame length, decoder)
FRAMES: dict[int, tuple[int, FrameDecoder]] = {
    _SYNC_P << 8 | ord("T"): (25, _position(Telemetry)),
    _SYNC_P << 8 | ord("M"): (25, _position(StartMeasuring)),
    _SYNC_P << 8 | ord("S"): (6, _timestamp_only(ProbePositionRequest)),
    _SYNC_R << 8 | ord("O"): (6, _timestamp_only(Ack)),
    _SYNC_R << 8 | ord("M"): (8, _with_depth(DepthReport)),
    _SYNC_R << 8 | ord("F"): (8, _with_depth(Finished)),
    _SYNC_R << 8 | ord("P"): (8, _with_depth(ProbePosition)),
}


class ReferenceParser:
    """WAIT_SYNC -> TYPE -> DATA (to the frame's length) -> checksum -> decode."""

    def __init__(self) -> None:
        self.state = WAIT_SYNC
        self.frame = bytearray()
        self.length = 0
        self.decode: FrameDecoder = _no_frame
        self.frames_decoded = 0
        self.errors = 0

    def feed(self, data: bytes | bytearray) -> list[Message]:
        out: list[Message] = []
        state = self.state
        frame = self.frame
        length = self.length
        decode = self.decode
        frames = FRAMES
        for byte in data:
            if state == WAIT_SYNC:
                if byte in (_SYNC_P, _SYNC_R):
                    frame = bytearray((byte,))
                    state = TYPE
            elif state == TYPE:
                entry = frames.get(frame[0] << 8 | byte)
                if entry is None:
                    self.errors += 1
                    state = WAIT_SYNC
                else:
                    length, decode = entry
                    frame.append(byte)
                    state = DATA
            else:
                frame.append(byte)
                if len(frame) == length:
                    state = WAIT_SYNC
                    if sum(frame[:-2]) & 0xFFFF != int.from_bytes(frame[-2:], "big"):
                        self.errors += 1
                        continue
                    message = decode(frame)
                    if message is None:
                        self.errors += 1
                    else:
                        out.append(message)
                        self.frames_decoded += 1
        self.state = state
        self.frame = frame
        self.length = length
        self.decode = decode
        return out
