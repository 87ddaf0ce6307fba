"""Hypothesis strategies for the wire codec, and a model of the parser to check it against.

The strategies cover the full range the wire can carry for every field of
every message, `P-M` in both its lengths (the manual's 25 bytes, the
firmware's 26 with a mode byte). The model (`model_events`) is the resynchronisation rule of
PROTOCOL.md written as plainly as possible over a whole stream: at each
offset, a complete valid frame is taken whole, anything else costs one byte.
Its frame check (`model_frame`) decodes with `int.from_bytes` and the
messages' validating constructors, independently of `frames.py`'s structs.
"""

from __future__ import annotations

from itertools import pairwise
from typing import Any, NamedTuple

from hypothesis import strategies as st

from cc_daemon.core.errors import FieldError
from cc_daemon.core.protocol import (
    Ack,
    DepthReport,
    FaultReport,
    Finished,
    Message,
    ProbeDown,
    ProbePosition,
    ProbePositionRequest,
    ProbeUp,
    Sender,
    StartMeasuring,
    Telemetry,
    encode,
)

# ------------------------------------------------------------------ fields

# Wire ranges, written out here rather than imported, so a wrong constant in
# the codec cannot make its own test pass.
timestamps = st.integers(0, 0xFFFF)
lon_e7 = st.integers(-1_800_000_000, 1_800_000_000)
lat_e7 = st.integers(-900_000_000, 900_000_000)
alt_mm = st.integers(-0xFFFFFF, 0xFFFFFF)  # sign byte + 3-byte magnitude
sonar_mm = st.integers(0, 0xFFFFFFFF)
confidence = st.integers(0, 100)
depth_mm = st.integers(0, 0xFFFF)
modes = st.none() | st.integers(0, 0xFF)  # None: the manual's 25-byte M

# ------------------------------------------------------------------ messages

telemetry = st.builds(Telemetry, timestamps, lon_e7, lat_e7, alt_mm, sonar_mm, confidence)


def reads_as_25_bytes(frame: bytes) -> bool:
    """A 26-byte `M` whose first 25 bytes also check out as the manual's `M`.

    Only possible with some non-zero mode bytes (bytes 0-22 must sum to
    256 * mode + the 26-byte checksum's high byte); the firmware always sends
    mode 0, for which it cannot happen. The 25-byte reading wins such a tie.
    """
    return len(frame) == 26 and sum(frame[:23]) == int.from_bytes(frame[23:25], "big")


start_measuring = st.builds(
    StartMeasuring, timestamps, lon_e7, lat_e7, alt_mm, sonar_mm, confidence, modes
).filter(lambda message: not reads_as_25_bytes(encode(message)))
probe_requests = st.builds(ProbePositionRequest, timestamps)
probe_ups = st.builds(ProbeUp, timestamps)
probe_downs = st.builds(ProbeDown, timestamps)
acks = st.builds(Ack, timestamps)
depth_reports = st.builds(DepthReport, timestamps, depth_mm)
finished = st.builds(Finished, timestamps, depth_mm)
probe_positions = st.builds(ProbePosition, timestamps, depth_mm)
fault_reports = st.builds(FaultReport, timestamps, depth_mm)

autopilot_messages: st.SearchStrategy[Message] = st.one_of(
    telemetry, start_measuring, probe_requests, probe_ups, probe_downs
)
cc_messages: st.SearchStrategy[Message] = st.one_of(
    acks, depth_reports, finished, probe_positions, fault_reports
)
messages: st.SearchStrategy[Message] = st.one_of(autopilot_messages, cc_messages)

# ------------------------------------------------------------------ garbage

SYNCS = b"PR"
TYPE_BYTES = b"TMSGOFPUDL"


@st.composite
def frame_prefixes(draw: st.DrawFn) -> bytes:
    """The start of a valid frame, cut short: it claims more bytes than it has."""
    frame = encode(draw(messages))
    return frame[: draw(st.integers(1, len(frame) - 1))]


@st.composite
def corrupted_frames(draw: st.DrawFn) -> bytes:
    """A valid frame with one byte changed: usually a bad checksum or field."""
    frame = bytearray(encode(draw(messages)))
    index = draw(st.integers(0, len(frame) - 1))
    frame[index] ^= draw(st.integers(1, 255))
    return bytes(frame)


# Line noise, biased towards what stresses a resynchronising parser: sync
# bytes, sync + type pairs, cut-off and corrupted frames, and now and then a
# whole valid frame (garbage that decodes: an extra message, honestly found).
garbage: st.SearchStrategy[bytes] = st.lists(
    st.one_of(
        st.binary(max_size=8),
        st.lists(st.sampled_from(SYNCS + TYPE_BYTES + b"\x00\x48"), max_size=6).map(bytes),
        frame_prefixes(),
        corrupted_frames(),
        messages.map(encode),
    ),
    max_size=3,
).map(b"".join)

# Short frames with no field constraints, which garbage can form by accident.
EATERS: list[tuple[bytes, int]] = [
    (b"RO", 6),
    (b"PS", 6),
    (b"PU", 6),
    (b"PD", 6),
    (b"RM", 8),
    (b"RF", 8),
    (b"RP", 8),
]


@st.composite
def frame_eaters(draw: st.DrawFn, following: bytes) -> bytes:
    """Garbage that, together with the first bytes of `following`, forms a valid
    frame: the one way garbage can cost a real frame. Empty when the chosen
    overlap cannot be made to check out."""
    head, length = draw(st.sampled_from(EATERS))
    overlap = draw(st.integers(1, length - 4))  # the timestamp stays in the garbage
    own = length - overlap
    frame = bytearray(head + draw(st.binary(min_size=own - 2, max_size=own - 2)))
    frame += following[:overlap]
    if overlap == 1:
        # The checksum's low byte is the following frame's sync byte: pick the
        # timestamp's low byte to match it, then the high byte the sum gives.
        rest = sum(frame[: length - 2]) - frame[3]
        frame[3] = (following[0] - rest) & 0xFF
        frame[length - 2] = sum(frame[: length - 2]) >> 8
    else:
        # The whole checksum is the following frame's bytes: solve for the timestamp.
        wanted = int.from_bytes(frame[-2:], "big") - (sum(frame[:-2]) - frame[2] - frame[3])
        if not 0 <= wanted <= 510:
            return b""
        frame[2], frame[3] = min(wanted, 255), wanted - min(wanted, 255)
    assert sum(frame[:-2]) % 65536 == int.from_bytes(frame[-2:], "big")
    return bytes(frame[:own])


# Garbage that can never start a frame: no sync byte at all.
sync_free_garbage: st.SearchStrategy[bytes] = st.binary(max_size=12).map(
    lambda data: data.replace(b"P", b"").replace(b"R", b"")
)

senders = st.sampled_from([Sender.AUTOPILOT, Sender.CC, Sender.BOTH])


@st.composite
def split(draw: st.DrawFn, data: bytes) -> list[bytes]:
    """`data` cut at arbitrary points (empty chunks included)."""
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=12)))
    bounds = [0, *cuts, len(data)]
    return [data[a:b] for a, b in pairwise(bounds)]


# ------------------------------------------------------------------ the model

# (sync, type) -> (frame length, message class), straight from PROTOCOL.md's tables.
AUTOPILOT_FRAMES: dict[bytes, tuple[int, type[Any]]] = {
    b"PT": (25, Telemetry),
    b"PM": (25, StartMeasuring),
    b"PS": (6, ProbePositionRequest),
    b"PU": (6, ProbeUp),
    b"PD": (6, ProbeDown),
}
G_ALIAS_FRAME: dict[bytes, tuple[int, type[Any]]] = {b"PG": (25, StartMeasuring)}
CC_FRAMES: dict[bytes, tuple[int, type[Any]]] = {
    b"RO": (6, Ack),
    b"RM": (8, DepthReport),
    b"RF": (8, Finished),
    b"RP": (8, ProbePosition),
    b"RL": (8, FaultReport),
}


def frames_for(
    senders: Sender, *, accept_g_alias: bool = False
) -> dict[bytes, tuple[int, type[Any]]]:
    table: dict[bytes, tuple[int, type[Any]]] = {}
    if senders in (Sender.AUTOPILOT, Sender.BOTH):
        table |= AUTOPILOT_FRAMES
        if accept_g_alias:
            table |= G_ALIAS_FRAME
    if senders in (Sender.CC, Sender.BOTH):
        table |= CC_FRAMES
    return table


def _signed(field: bytes) -> int | None:
    magnitude = int.from_bytes(field[1:], "big")
    return {0: magnitude, 1: -magnitude}.get(field[0])


def model_frame(frame: bytes, cls: type[Any]) -> Message | str:
    """The message in one complete frame, or the error kind that rejects it."""
    if sum(frame[:-2]) % 65536 != int.from_bytes(frame[-2:], "big"):
        return "bad_checksum"
    timestamp = int.from_bytes(frame[2:4], "big")
    if len(frame) == 6:
        return cls(timestamp)
    if len(frame) == 8:
        return cls(timestamp, int.from_bytes(frame[4:6], "big"))
    lon, lat, alt = _signed(frame[4:9]), _signed(frame[9:14]), _signed(frame[14:18])
    if lon is None or lat is None or alt is None:
        return "bad_field"
    mode = (frame[23],) if len(frame) == 26 else ()  # the firmware's P-M
    try:
        return cls(timestamp, lon, lat, alt, int.from_bytes(frame[18:22], "big"), frame[22], *mode)
    except FieldError:  # latitude, longitude or confidence out of range
        return "bad_field"


class ModelEvent(NamedTuple):
    offset: int
    data: bytes
    result: Message | str  # a message, or an error kind


def model_events(
    stream: bytes, senders: Sender = Sender.BOTH, *, accept_g_alias: bool = False
) -> list[ModelEvent]:
    """Every frame and error in a complete stream, in order, by the plain rule:
    a valid frame is taken whole; any failed frame start costs one byte. A
    `P-M` whose 25-byte checksum fails is read again as 26 bytes (when the
    stream has a 26th), and reported whole if that fails too."""
    table = frames_for(senders, accept_g_alias=accept_g_alias)
    syncs = {key[0] for key in table}
    out: list[ModelEvent] = []
    pos = 0
    while pos < len(stream):
        if stream[pos] not in syncs:
            pos += 1  # cannot start a frame: discarded silently
            continue
        if pos + 1 == len(stream):
            out.append(ModelEvent(pos, stream[pos:], "truncated"))
            pos += 1
            continue
        entry = table.get(stream[pos : pos + 2])
        if entry is None:
            out.append(ModelEvent(pos, stream[pos : pos + 2], "unknown_type"))
            pos += 1
            continue
        length, cls = entry
        frame = stream[pos : pos + length]
        if len(frame) < length:
            out.append(ModelEvent(pos, frame, "truncated"))
            pos += 1
            continue
        result = model_frame(frame, cls)
        if result == "bad_checksum" and stream[pos : pos + 2] == b"PM" and pos + 26 <= len(stream):
            frame = stream[pos : pos + 26]
            result = model_frame(frame, cls)
        out.append(ModelEvent(pos, frame, result))
        pos += len(frame) if not isinstance(result, str) else 1  # 26 for a firmware M
    return out
