"""`cc-daemon decode`: turn frames into lines a person can read.

Input is hex on the command line, a byte stream on stdin (raw bytes, or hex
text with `--hex`), or a live serial line (`--port`). Output is one line per
frame or per error, plain or JSON, then a summary line on stderr (`# N frames,
M errors (...), K bytes skipped`, the same for every input). The exit status
says whether any corrupt frame was found: 0 clean, 1 errors found; raw input
that decodes to nothing and looks like hex text is a usage error (2), pointing
at `--hex`.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Iterable, Iterator
from typing import IO, Any

from cc_daemon.core.protocol import CorruptFrame, Message, Parser, ParserStats, Sender, as_dict

_SEPARATORS = re.compile(r"[\s,:;]+")
# Hex text as people paste it: digits, blanks, separators, 0x prefixes.
_HEX_TEXT = re.compile(rb"[\s,:;]*(?:(?:0[xX])?[0-9a-fA-F]+[\s,:;]*)+")
HEX_SNIFF_BYTES = 4096  # how much of a raw stream is kept to tell hex text


def looks_like_hex(head: bytes) -> bool:
    """Whether raw input is in fact hex text (`50 53 00 48 00 EB`), from its first bytes."""
    return _HEX_TEXT.fullmatch(head) is not None and any(c in b"0123456789" for c in head)


def summary_line(stats: ParserStats) -> str:
    """`# N frames, M errors (...), K bytes skipped`: the last line of every decode."""
    return (
        f"# {stats.frames_decoded} frames, {stats.errors} errors "
        f"({stats.bad_checksum} bad checksum, {stats.unknown_type} unknown type, "
        f"{stats.bad_field} bad field, {stats.truncated} truncated), "
        f"{stats.bytes_discarded} bytes skipped"
    )


class HexInputError(ValueError):
    """Hex text that is not hex."""


def parse_hex(text: str) -> bytes:
    """`"50 53 00 48 00 EB"`, `"50530048 00EB"`, `"0x50,0x53"` -> bytes.

    Tokens are separated by blanks, commas, colons or semicolons; each is an
    even number of hex digits, optionally after `0x`.
    """
    out = bytearray()
    for token in _SEPARATORS.split(text.strip()):
        if not token:
            continue
        body = token[2:] if token[:2] in ("0x", "0X") else token
        if not body or len(body) % 2 or not all(c in "0123456789abcdefABCDEF" for c in body):
            raise HexInputError(f"not hex bytes: {token!r}")
        out += bytes.fromhex(body)
    return bytes(out)


def format_event(event: Message | CorruptFrame, *, as_json: bool) -> str:
    if isinstance(event, CorruptFrame):
        if as_json:
            return json.dumps(
                {"error": str(event.kind), "bytes": event.hex(), "detail": event.detail}
            )
        return f"ERROR {event.kind}: {event.hex()} ({event.detail})"
    fields: dict[str, Any] = as_dict(event)
    if as_json:
        return json.dumps(fields)
    name = fields.pop("frame")
    text = " ".join(f"{key}={value}" for key, value in fields.items())
    if hasattr(event, "lat_deg"):
        text += f"  ({event.lat_deg:.7f}, {event.lon_deg:.7f})"  # type: ignore[union-attr]
    return f"{name} {text}"


def decode_chunks(
    chunks: Iterable[bytes], *, accept_g_alias: bool = False, parser: Parser | None = None
) -> Iterator[Message | CorruptFrame]:
    """Every frame and error in a stream, in order, ending with any truncated frame.

    Pass a `parser` (listening to both senders) to read its statistics afterwards.
    """
    if parser is None:
        parser = Parser(Sender.BOTH, accept_g_alias=accept_g_alias)
    for chunk in chunks:
        yield from parser.events(chunk)
    yield from parser.close()


def read_stdin_chunks(stream: IO[bytes], *, hex_text: bool) -> Iterator[bytes]:
    if hex_text:
        for line in stream:
            yield parse_hex(line.decode("ascii", "replace"))
    else:
        while chunk := stream.read1(4096) if hasattr(stream, "read1") else stream.read(4096):
            yield chunk


def print_events(
    events: Iterable[Message | CorruptFrame], *, as_json: bool, out: IO[str] | None = None
) -> int:
    """Print each event to `out` (the current `sys.stdout` by default); return 1
    if any was an error, else 0."""
    # Looked up at call time: a default of `sys.stdout` would pin the stream
    # that existed at import, bypassing any later redirection.
    out = sys.stdout if out is None else out
    status = 0
    for event in events:
        if isinstance(event, CorruptFrame):
            status = 1
        print(format_event(event, as_json=as_json), file=out, flush=True)
    return status


def usage_problem(args: argparse.Namespace) -> str | None:
    """Options that do not apply together are refused, not ignored."""
    if args.port:
        if args.hex:
            return "hex arguments and --port do not go together: decode one or the other"
        if args.hex_stdin:
            return "--hex reads stdin; with --port the bytes come from the port"
        return None
    for option, given in (("--baudrate", args.baudrate is not None), ("--shared", args.shared)):
        if given:
            return f"{option} applies only with --port"
    if args.hex and args.hex_stdin:
        return "--hex reads hex text from stdin; hex arguments are decoded as they are"
    return None


def keeping_head(chunks: Iterable[bytes], head: bytearray, size: int) -> Iterator[bytes]:
    """The chunks unchanged, keeping a copy of the first `size` bytes in `head`."""
    for chunk in chunks:
        if len(head) < size:
            head += chunk[: size - len(head)]
        yield chunk


def checked_baudrate(baudrate: int | None) -> int:
    """--baudrate for decode, validated exactly as the daemon's serial.baudrate."""
    from cc_daemon.config import load_settings

    # Only the flag: no file, no environment (decode reads neither).
    settings = load_settings(None, {"serial": {"baudrate": baudrate}}, env={}, search_paths=())
    return settings.serial.baudrate
