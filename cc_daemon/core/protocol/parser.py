"""The streaming frame parser: bytes in, messages out, never an exception.

`Parser.feed` accepts any chunk of the byte stream (a whole capture, 4 KiB
reads, one byte at a time) and returns the messages completed by it. Bad input
never raises: a bad checksum, an unknown type byte after a sync byte or an
invalid field is counted in `stats`, logged at debug with its raw bytes,
handed to the `on_error` callback as a `CorruptFrame`, and the parser
resynchronises at the next sync byte *after the failed frame's first byte*, so
a valid frame that starts inside a corrupt one is still found.

`P-M` comes in two lengths (the manual's 25 bytes, the deployed firmware's
26 with a mode byte). When the 25-byte reading's checksum fails the parser
waits for the 26th byte and tries that reading before calling the frame
corrupt, so a firmware `M` is never split into a bad frame plus garbage,
however the stream is chunked or paused.

The buffer is bounded: between calls it holds less than one maximal frame
(26 bytes), whatever was fed. At the end of the stream `close` reports a frame
cut short as truncated and still decodes any complete frame that starts
inside it.

Timestamps are information only: nothing here rejects, reorders or drops a
frame because of its timestamp.

`events_in_runs` is `events` for a reader that hears `P-T` frames read together
as one instant (the daemon): two or more back to back come as one
`TelemetryRun`, every frame checked as alone, only the first and last decoded
(`runs.py`). Under a flood of telemetry that is about a fifth of the work a
byte (`benchmarks/parser.py`).

It logs through the standard library's `logging` (logger "cc_daemon.core.protocol"),
so as a library it is silent unless its user configures logging; the daemon's
logging setup routes those records into its own output.
"""

import logging
import re
from collections.abc import Callable
from dataclasses import dataclass
from enum import Flag, StrEnum
from typing import Any, NamedTuple

from cc_daemon.core.errors import FrameError
from cc_daemon.core.protocol.frames import (
    AUTOPILOT_LAYOUTS,
    CC_LAYOUTS,
    G_ALIAS_LAYOUT,
    MAX_FRAME_LENGTH,
    POSITION_LENGTH,
    AutopilotType,
    Decoder,
    Layout,
    Sync,
)
from cc_daemon.core.protocol.messages import Message
from cc_daemon.core.protocol.runs import TelemetryRun, run_length

_log = logging.getLogger("cc_daemon.protocol")


class Sender(Flag):
    """Whose frames a parser listens for."""

    AUTOPILOT = 1  # sync "P"
    CC = 2  # sync "R"
    BOTH = AUTOPILOT | CC


class ErrorKind(StrEnum):
    BAD_CHECKSUM = "bad_checksum"
    UNKNOWN_TYPE = "unknown_type"
    BAD_FIELD = "bad_field"
    TRUNCATED = "truncated"


class CorruptFrame(NamedTuple):
    """Bytes that looked like the start of a frame and were not one."""

    kind: ErrorKind
    data: bytes
    detail: str

    def hex(self) -> str:
        return self.data.hex(" ").upper()


@dataclass(slots=True)
class ParserStats:
    """Counters since the parser was made. Every byte fed ends up in exactly one
    of: a decoded frame, `bytes_discarded`, or the pending buffer."""

    frames_decoded: int = 0
    bad_checksum: int = 0
    unknown_type: int = 0
    bad_field: int = 0
    truncated: int = 0
    bytes_received: int = 0
    bytes_discarded: int = 0
    # Of those discarded, the bytes no corrupt frame reported: no frame could start
    # in them (an `M` whose sync byte flipped is such bytes, and nothing else says so).
    bytes_unframed: int = 0

    @property
    def errors(self) -> int:
        return self.bad_checksum + self.unknown_type + self.bad_field + self.truncated


ErrorCallback = Callable[[CorruptFrame], None]
_SYNC_PATTERNS = {
    Sender.AUTOPILOT: re.compile(b"P"),
    Sender.CC: re.compile(b"R"),
    Sender.BOTH: re.compile(b"[PR]"),
}
_TELEMETRY = Sync.AUTOPILOT << 8 | AutopilotType.TELEMETRY
_TELEMETRY_START = bytes((Sync.AUTOPILOT, AutopilotType.TELEMETRY))


def _good_telemetry_at(buf: bytearray, pos: int, end: int) -> bool:
    """A whole `P-T` with a right checksum starts at `pos` (its fields unchecked): the
    cheap test before looking for a run, so that frames failing one by one (line
    noise, a babbling autopilot) are never checked twice over."""
    stop = pos + POSITION_LENGTH
    return (
        stop <= end
        and buf[pos : pos + 2] == _TELEMETRY_START
        and sum(buf[pos : stop - 2]) & 0xFFFF == buf[stop - 2] << 8 | buf[stop - 1]
    )


class Parser:
    """A resynchronising parser for the autopilot link. See the module docstring."""

    def __init__(
        self,
        senders: Sender = Sender.BOTH,
        *,
        accept_g_alias: bool = False,
        on_error: ErrorCallback | None = None,
    ) -> None:
        layouts: dict[int, Layout] = {}
        syncs: set[int] = set()
        if Sender.AUTOPILOT in senders:
            layouts.update(AUTOPILOT_LAYOUTS)
            if accept_g_alias:
                layouts.update(G_ALIAS_LAYOUT)
            syncs.add(Sync.AUTOPILOT)
        if Sender.CC in senders:
            layouts.update(CC_LAYOUTS)
            syncs.add(Sync.CC)
        # Plain tuples: unpacking one is cheaper than two attribute loads per frame.
        self._layouts: dict[int, tuple[int, Decoder, Decoder | None]] = {
            key: (layout.length, layout.decode, layout.longer) for key, layout in layouts.items()
        }
        self._syncs = frozenset(syncs)
        self._search = _SYNC_PATTERNS[senders].search
        self._buf = bytearray()
        # How many buffered bytes the next parse needs to make progress: the
        # pending frame's length once its type is known. Feeds that leave the
        # buffer short of it only append, which keeps one-byte feeds cheap.
        self._need = 2
        # Where the bytes of the last corrupt frame reported end, in the buffer: the
        # bytes skipped before it were that frame's, not unframed ones.
        self._covered = 0
        self.on_error = on_error
        self.stats = ParserStats()

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame (always < 26)."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Message]:
        """Add `data` to the stream; return the messages it completed, in order."""
        buf = self._buf
        buf += data
        self.stats.bytes_received += len(data)
        if len(buf) < self._need:
            return []
        out: list[Message] = []
        self._parse(out, self._report)
        return out

    def events(self, data: bytes | bytearray | memoryview) -> list[Message | CorruptFrame]:
        """Like `feed`, but corrupt frames come back too, in stream order."""
        out: list[Message | CorruptFrame] = []
        self._buf += data
        self.stats.bytes_received += len(data)
        self._parse(out, self._reporting_to(out))  # type: ignore[arg-type]
        return out

    def events_in_runs(
        self, data: bytes | bytearray | memoryview
    ) -> list[Message | CorruptFrame | TelemetryRun]:
        """Like `events`, but two or more `P-T` frames back to back come back as one
        `TelemetryRun`: each frame checked as alone and counted in `stats`, only the
        first and the last decoded (`runs`). For a reader that hears a run read
        together as one instant, as the daemon does: a flood's hot path."""
        out: list[Message | CorruptFrame | TelemetryRun] = []
        self._buf += data
        self.stats.bytes_received += len(data)
        self._parse(out, self._reporting_to(out), runs=True)  # type: ignore[arg-type]
        return out

    def close(self) -> list[Message | CorruptFrame]:
        """End of stream: what is left in the buffer, as events in stream order.

        The frame the buffer starts with can no longer be completed, so it is
        reported as truncated (with every byte left) and, as after any failed
        frame, parsing resumes from its second byte: a complete frame that
        starts inside it is still decoded. The parser is then empty and can
        take a new stream.
        """
        out: list[Message | CorruptFrame] = []
        report = self._reporting_to(out)
        buf = self._buf
        # feed's fast path may have left a lone non-sync byte unparsed: drop it
        # first. `final`: a 25-byte `M` is judged now, its 26th byte never comes.
        self._parse(out, report, final=True)  # type: ignore[arg-type]
        while buf:
            report(
                CorruptFrame(
                    ErrorKind.TRUNCATED,
                    bytes(buf),
                    f"stream ended {len(buf)} bytes into a frame",
                )
            )
            del buf[:1]
            self.stats.bytes_discarded += 1
            self._covered = len(buf)  # the truncated frame's: every byte left
            self._parse(out, report, final=True)  # type: ignore[arg-type]
        self._need = 2
        self._covered = 0
        return out

    # ------------------------------------------------------------ internals

    def _reporting_to(self, out: list[Any]) -> ErrorCallback:
        """A corrupt frame's report that also puts it in `out`, in stream order."""

        def report(error: CorruptFrame) -> None:
            self._report(error)
            out.append(error)

        return report

    def _report(self, error: CorruptFrame) -> None:
        stats = self.stats
        if error.kind is ErrorKind.BAD_CHECKSUM:
            stats.bad_checksum += 1
        elif error.kind is ErrorKind.UNKNOWN_TYPE:
            stats.unknown_type += 1
        elif error.kind is ErrorKind.BAD_FIELD:
            stats.bad_field += 1
        else:
            stats.truncated += 1
        if _log.isEnabledFor(logging.DEBUG):
            _log.debug(
                "corrupt frame",
                extra={
                    "fields": {
                        "kind": str(error.kind),
                        "bytes": error.hex(),
                        "detail": error.detail,
                    }
                },
            )
        if self.on_error is not None:
            self.on_error(error)

    @staticmethod
    def _checksum_detail(buf: bytearray, pos: int, stop: int, two_lengths: bool) -> str:
        sent = buf[stop - 2] << 8 | buf[stop - 1]
        summed = sum(buf[pos : stop - 2]) & 0xFFFF
        detail = f"checksum 0x{sent:04X}, bytes sum to 0x{summed:04X}"
        if two_lengths and stop - pos == MAX_FRAME_LENGTH:
            short = sum(buf[pos : stop - 3]) & 0xFFFF
            sent_short = buf[stop - 3] << 8 | buf[stop - 2]
            detail += (
                f" (as 26 bytes; as 25 bytes: checksum 0x{sent_short:04X}, "
                f"bytes sum to 0x{short:04X})"
            )
        return detail

    def _parse(
        self, out: list[Message], report: ErrorCallback, *, final: bool = False, runs: bool = False
    ) -> None:
        buf = self._buf
        end = len(buf)
        get = self._layouts.get
        syncs = self._syncs
        pos = 0
        stop = 0
        decoded = 0
        discarded = 0
        unframed = 0
        covered = self._covered
        while pos + 1 < end:
            key = buf[pos] << 8 | buf[pos + 1]
            layout = get(key)
            if layout is None:
                if buf[pos] in syncs:
                    report(
                        CorruptFrame(
                            ErrorKind.UNKNOWN_TYPE,
                            bytes(buf[pos : pos + 2]),
                            f"type byte 0x{buf[pos + 1]:02X} after sync {chr(buf[pos])!r}",
                        )
                    )
                    covered = max(covered, pos + 2)
                    discarded += 1
                    pos += 1
                    continue
                found = self._search(buf, pos + 1)
                nxt = end if found is None else found.start()
                discarded += nxt - pos
                unframed += max(0, nxt - max(pos, covered))
                pos = nxt
                continue
            length, decode, longer = layout
            stop = pos + length
            if stop > end:
                break  # wait for the rest of the frame
            sent = buf[stop - 2] << 8 | buf[stop - 1]
            if sum(buf[pos : stop - 2]) & 0xFFFF == sent:
                # A good P-T and another after it: a run of them (`runs`), however long.
                if runs and key == _TELEMETRY and _good_telemetry_at(buf, stop, end):
                    count = run_length(buf, pos, end)
                    if count > 1:
                        block = bytes(buf[pos : pos + count * length])
                        out.append(TelemetryRun(block, count, decode))  # type: ignore[arg-type]
                        decoded += count
                        pos = stop = pos + count * length
                        continue
            else:
                if longer is not None and (stop < end or not final):
                    # Maybe the firmware's 26-byte `M`: judge it on its 26th byte.
                    stop += 1
                    if stop > end:
                        break  # wait for it, whatever pause the line takes
                    sent = buf[stop - 2] << 8 | buf[stop - 1]
                    if sum(buf[pos : stop - 2]) & 0xFFFF == sent:
                        decode = longer
                if decode is not longer:
                    report(
                        CorruptFrame(
                            ErrorKind.BAD_CHECKSUM,
                            bytes(buf[pos:stop]),
                            self._checksum_detail(buf, pos, stop, longer is not None),
                        )
                    )
                    covered = max(covered, stop)
                    discarded += 1
                    pos += 1
                    continue
            try:
                out.append(decode(buf, pos))
            except FrameError as exc:
                report(CorruptFrame(ErrorKind.BAD_FIELD, bytes(buf[pos:stop]), exc.detail))
                covered = max(covered, stop)
                discarded += 1
                pos += 1
                continue
            decoded += 1
            pos = stop
        if pos == end - 1 and buf[pos] not in syncs:
            discarded += 1  # a lone non-sync byte can never start a frame
            if pos >= covered:
                unframed += 1
            pos = end
        del buf[:pos]
        self._covered = max(0, covered - pos)
        assert len(buf) < MAX_FRAME_LENGTH
        self._need = stop - pos if pos + 1 < end else 2
        self.stats.frames_decoded += decoded
        self.stats.bytes_discarded += discarded
        self.stats.bytes_unframed += unframed
