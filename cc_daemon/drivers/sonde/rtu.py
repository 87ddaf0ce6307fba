"""Modbus RTU frames: the bytes of a read request, and replies found in a byte stream.

Pure (no I/O, no clock): `read_request` builds a function-3 request;
`ReplyParser` takes whatever bytes came off the line and yields every frame
whose CRC is good, whoever sent it and whatever its function code, so the
reader can tell a reply from another slave (`wrong_slave`) or with another
function (`wrong_function`) from line noise (`crc`). Bytes that start no
valid frame are dropped one at a time and counted, never raised.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["READ_HOLDING", "Reply", "ReplyParser", "crc16", "read_request", "reply_frame"]

READ_HOLDING = 0x03
_READ_FUNCTIONS = (0x03, 0x04)  # replies with a byte count after the function code
_MAX_FRAME = 256  # an RTU frame is at most 256 bytes (the spec's limit)


def crc16(data: bytes) -> int:
    """Modbus CRC-16 (polynomial 0xA001 reflected, start 0xFFFF)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def _framed(body: bytes) -> bytes:
    return body + crc16(body).to_bytes(2, "little")


def read_request(slave: int, address: int, count: int, function: int = READ_HOLDING) -> bytes:
    """The 8 bytes asking `slave` for `count` registers from protocol `address`."""
    return _framed(bytes([slave, function]) + address.to_bytes(2, "big") + count.to_bytes(2, "big"))


def reply_frame(slave: int, function: int, registers: list[int]) -> bytes:
    """A read reply's bytes (for tests and simulators)."""
    data = b"".join(r.to_bytes(2, "big") for r in registers)
    return _framed(bytes([slave, function, len(data)]) + data)


class Reply(NamedTuple):
    """One frame with a good CRC. `exception` is set for an exception response."""

    slave: int
    function: int  # without the exception bit
    data: bytes  # the register bytes of a read reply
    exception: int | None = None

    @property
    def registers(self) -> list[int]:
        return [int.from_bytes(self.data[i : i + 2], "big") for i in range(0, len(self.data), 2)]


class ReplyParser:
    """Feed bytes, take replies. Keeps an incomplete frame for the next feed."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.dropped = 0  # bytes that began no valid frame

    @property
    def pending(self) -> int:
        return len(self._buffer)

    def feed(self, data: bytes) -> list[Reply]:
        self._buffer += data
        replies: list[Reply] = []
        buf = self._buffer
        while len(buf) >= 5:
            function = buf[1]
            if function & 0x80:
                length = 5
            elif function in _READ_FUNCTIONS:
                length = 5 + buf[2]
            else:
                length = 0
            if length == 0 or length > _MAX_FRAME:
                del buf[0]
                self.dropped += 1
                continue
            if len(buf) < length:
                break
            frame = bytes(buf[:length])
            if crc16(frame[:-2]) != int.from_bytes(frame[-2:], "little"):
                del buf[0]  # search again from the next byte
                self.dropped += 1
                continue
            del buf[:length]
            if function & 0x80:
                replies.append(Reply(frame[0], function & 0x7F, b"", frame[2]))
            else:
                replies.append(Reply(frame[0], function, frame[3:-2]))
        return replies

    def clear(self) -> int:
        """Forget an incomplete frame; how many bytes it held."""
        n = len(self._buffer)
        self._buffer.clear()
        return n
