"""Telemetry frames back to back, checked together: the parser's hot path.

An autopilot streams `P-T` fixes; read in chunks, they arrive as runs of 25-byte
frames back to back. This module owns checking such a run without a Python
step per byte or per field: `run_length` says how many whole `P-T` frames
starting at a position are each exactly what the parser accepts one by one
(sync `P`, type `T`, sign bytes 0 or 1, longitude and latitude in range,
confidence at most 100, checksum right), using column slices of the run's
bytes (every 25th byte from an offset), `bytes.lstrip` and one checksum call a
frame. A frame that fails any check ends the run there; the parser judges it
on its own, as always, so what is reported corrupt does not change.

`TelemetryRun` is such a run as the parser hands it on: a sequence of
`Telemetry` whose first and last are decoded at once and the others only if
asked for (debug logging, a journal keeping every fix). The daemon hears a run
read together as one instant and journals its last fix: a flood of telemetry
costs it one checksum call a frame, not a decode per frame.

Pure: bytes in, counts and messages out.
"""

import struct
import zlib
from collections.abc import Sequence
from operator import index as as_index
from typing import overload

from cc_daemon.core.protocol.frames import POSITION_LENGTH, Decoder
from cc_daemon.core.protocol.messages import (
    CONFIDENCE_MAX,
    LAT_E7_MAX,
    LON_E7_MAX,
    Telemetry,
)

__all__ = ["TelemetryRun", "run_length"]

_LENGTH = POSITION_LENGTH  # 25
_BODY = _LENGTH - 2  # what the checksum sums
_SYNC, _TYPE = b"P", b"T"
_SIGNS = b"\x00\x01"
_SIGN_OFFSETS = (4, 9, 14)  # longitude, latitude, altitude
_CONFIDENCE_OFFSET = 22
_CONFIDENCES = bytes(range(CONFIDENCE_MAX + 1))
_LON_TOP_OFFSET, _LAT_TOP_OFFSET = 5, 10  # the magnitudes' most significant bytes
# A magnitude whose top byte is below these is in range whatever its other bytes.
_LON_TOP_SAFE = LON_E7_MAX >> 24  # 0x6B
_LAT_TOP_SAFE = LAT_E7_MAX >> 24  # 0x35
_CHECKED = struct.Struct(f">{_BODY}sH")  # what the checksum sums, and the checksum
_MAGNITUDES = struct.Struct(">5xIxI11x")
# A run is checked in windows: 8 frames (200 bytes), then eight times as many each
# time (a flood's 4 KiB read is three windows); a run cut short costs one window more.
_FIRST_WINDOW = 8
_GROWTH = 8


def _leading(column: bytes, allowed: bytes) -> int:
    """How many bytes at the start of `column` are among `allowed`."""
    return len(column) - len(column.lstrip(allowed))


def _in_range(block: bytes, count: int) -> int:
    """How many of the first `count` frames have longitude and latitude in range."""
    size = count * _LENGTH
    if (
        max(block[_LON_TOP_OFFSET:size:_LENGTH]) < _LON_TOP_SAFE
        and max(block[_LAT_TOP_OFFSET:size:_LENGTH]) < _LAT_TOP_SAFE
    ):
        return count
    for at, (lon, lat) in enumerate(_MAGNITUDES.iter_unpack(block[:size])):
        if lon > LON_E7_MAX or lat > LAT_E7_MAX:
            return at
    return count


def _checksums_right(block: bytes, count: int) -> int:
    """How many of the first `count` frames carry the sum of their bytes."""
    # adler32 started at 0 holds the bytes' sum in its low 16 bits (a frame's 23
    # bytes sum to at most 5,865, below adler's modulus): one C call a frame.
    adler = zlib.adler32
    for at, (body, sent) in enumerate(_CHECKED.iter_unpack(block[: count * _LENGTH])):
        if adler(body, 0) & 0xFFFF != sent:
            return at
    return count


def _valid_frames(block: bytes, count: int) -> int:
    """How many of the `count` frames `block` holds, from its start, the parser would
    decode one by one."""
    count = min(
        count,
        _leading(block[0::_LENGTH], _SYNC),
        _leading(block[1::_LENGTH], _TYPE),
        _leading(block[_CONFIDENCE_OFFSET::_LENGTH], _CONFIDENCES),
        *(_leading(block[offset::_LENGTH], _SIGNS) for offset in _SIGN_OFFSETS),
    )
    if count:
        count = _in_range(block, count)
    if count:
        count = _checksums_right(block, count)
    return count


def run_length(buf: bytes | bytearray, pos: int, end: int) -> int:
    """How many whole `P-T` frames start at `pos`, back to back before `end`, each
    one the parser would decode on its own.

    Checked in windows of `_FIRST_WINDOW` frames, then `_GROWTH` times as many each
    time, up to the first frame that fails: a call costs at most a few times the run
    it finds, plus a window, never the rest of the read for each run.
    """
    available = (end - pos) // _LENGTH
    count, window = 0, _FIRST_WINDOW
    while count < available:
        size = min(window, available - count)
        start = pos + count * _LENGTH
        good = _valid_frames(bytes(buf[start : start + size * _LENGTH]), size)
        count += good
        if good < size:
            break
        window *= _GROWTH
    return count


class TelemetryRun(Sequence[Telemetry]):
    """Two or more `P-T` frames back to back, read together, each checked as the
    parser checks one. `first` and `last` are decoded; the others when asked for."""

    __slots__ = ("_block", "_count", "_decode", "first", "last")

    def __init__(self, block: bytes, count: int, decode: Decoder) -> None:
        self._block = block
        self._decode = decode
        self._count = count
        self.first: Telemetry = decode(block, 0)  # type: ignore[assignment]
        self.last: Telemetry = decode(block, (count - 1) * _LENGTH)  # type: ignore[assignment]

    def __len__(self) -> int:
        return self._count

    @overload
    def __getitem__(self, item: int) -> Telemetry: ...

    @overload
    def __getitem__(self, item: slice) -> list[Telemetry]: ...

    def __getitem__(self, item: int | slice) -> Telemetry | list[Telemetry]:
        if isinstance(item, slice):
            return [self[at] for at in range(*item.indices(self._count))]
        at = as_index(item)
        if at < 0:
            at += self._count
        if not 0 <= at < self._count:
            raise IndexError(f"frame {item} of a run of {self._count}")
        if at == 0:
            return self.first
        if at == self._count - 1:
            return self.last
        return self._decode(self._block, at * _LENGTH)  # type: ignore[return-value]

    def __repr__(self) -> str:
        return f"TelemetryRun({self._count} P-T, first={self.first!r}, last={self.last!r})"
