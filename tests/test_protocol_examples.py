"""The checked example frames of PROTOCOL.md, byte for byte, and every decoder case several ways.

The table below is PROTOCOL.md's "Checked examples" (manual tables 6.3-6.15),
copied by hand: the hex strings and the decoded values are independent of the
codec, so a wrong layout, byte order or checksum fails here.
"""

from __future__ import annotations

import pytest

from cc_daemon.core.protocol import (
    Ack,
    AutopilotType,
    CorruptFrame,
    DepthReport,
    ErrorKind,
    Finished,
    Message,
    Parser,
    ProbePosition,
    ProbePositionRequest,
    Sender,
    StartMeasuring,
    Telemetry,
    encode,
)

MADRID = (72, -37260579, 404506308, 702385, 8219, 100)

# name -> (frame, decoded)
EXAMPLES: dict[str, tuple[str, Message]] = {
    "P-T": (
        "50 54 00 48 01 02 38 8D 23 00 18 1C 46 C4 00 0A B7 B1 00 00 20 1B 64 05 26",
        Telemetry(*MADRID),
    ),
    "P-M": (
        "50 4D 00 48 01 02 38 8D 23 00 18 1C 46 C4 00 0A B7 B1 00 00 20 1B 64 05 1F",
        StartMeasuring(*MADRID),
    ),
    "P-S": ("50 53 00 48 00 EB", ProbePositionRequest(72)),
    "R-O": ("52 4F 00 48 00 E9", Ack(72)),
    "R-M": ("52 4D 00 48 3D CC 01 F0", DepthReport(72, 15820)),
    "R-F": ("52 46 00 48 00 00 00 E0", Finished(72, 0)),
    "R-P": ("52 50 00 48 12 A8 01 A4", ProbePosition(72, 4776)),
}
# The manual's own P-T: its checksum 05 19 is wrong (the bytes sum to 05 26)...
MANUAL_P_T = bytes.fromhex(
    "50 54 00 48 01 02 38 8D 23 00 18 1C 46 C4 00 0A B7 B1 00 00 20 1B 64 05 19"
)
# ...but it is exactly right for the same bytes with type G: a valid P-G.
P_G = bytes.fromhex("50 47 00 48 01 02 38 8D 23 00 18 1C 46 C4 00 0A B7 B1 00 00 20 1B 64 05 19")


def frame(name: str) -> bytes:
    return bytes.fromhex(EXAMPLES[name][0])


def feed_and_close(parser: Parser, *chunks: bytes) -> list[Message | CorruptFrame]:
    events: list[Message | CorruptFrame] = []
    for chunk in chunks:
        events += parser.events(chunk)
    return events + parser.close()


def messages_of(events: list[Message | CorruptFrame]) -> list[Message]:
    return [event for event in events if not isinstance(event, CorruptFrame)]


# ---------------------------------------------------------------- the table


@pytest.mark.parametrize("name", EXAMPLES)
def test_example_decodes_to_the_listed_values(name: str) -> None:
    data, expected = EXAMPLES[name]
    parser = Parser()
    [message] = parser.feed(bytes.fromhex(data))
    assert message == expected
    assert type(message) is type(expected)
    assert message.frame == name
    assert parser.stats.frames_decoded == 1
    assert parser.stats.errors == 0
    assert parser.pending == 0


@pytest.mark.parametrize("name", EXAMPLES)
def test_example_reencodes_byte_for_byte(name: str) -> None:
    data, message = EXAMPLES[name]
    assert encode(message) == bytes.fromhex(data)


def test_example_fields_in_plain_units() -> None:
    telemetry = EXAMPLES["P-T"][1]
    assert isinstance(telemetry, Telemetry)
    assert telemetry.timestamp_s == 72
    assert telemetry.lon_e7 == -37260579
    assert telemetry.lat_e7 == 404506308
    assert telemetry.alt_mm == 702385
    assert telemetry.sonar_distance_mm == 8219
    assert telemetry.sonar_confidence_pct == 100
    # "lon -3.7260579°, lat 40.4506308° (Madrid), altitude 702.385 m"
    assert telemetry.lon_deg == pytest.approx(-3.7260579, abs=1e-9)
    assert telemetry.lat_deg == pytest.approx(40.4506308, abs=1e-9)
    assert telemetry.alt_m == pytest.approx(702.385)
    assert telemetry.sonar_distance_m == pytest.approx(8.219)


@pytest.mark.parametrize(
    ("name", "checksum"),
    [
        ("P-T", 1318),
        ("P-M", 1311),
        ("P-S", 235),
        ("R-O", 233),
        ("R-M", 496),
        ("R-F", 224),
        ("R-P", 420),
    ],
)
def test_example_checksums_are_the_sums_the_table_gives(name: str, checksum: int) -> None:
    data = frame(name)
    assert sum(data[:-2]) == checksum
    assert int.from_bytes(data[-2:], "big") == checksum


# ---------------------------------------------------------------- the manual's bad P-T


def test_manual_p_t_with_wrong_checksum_is_rejected_and_counted() -> None:
    assert sum(MANUAL_P_T[:-2]) == 0x0526  # what PROTOCOL.md says; the frame carries 05 19
    parser = Parser()
    events = feed_and_close(parser, MANUAL_P_T)
    assert messages_of(events) == []
    assert events[0] == CorruptFrame(ErrorKind.BAD_CHECKSUM, MANUAL_P_T, events[0].detail)
    assert parser.stats.bad_checksum == 1
    assert parser.stats.frames_decoded == 0
    assert parser.stats.bytes_discarded == len(MANUAL_P_T)


def test_manual_p_t_is_rejected_even_with_the_g_alias_on() -> None:
    parser = Parser(accept_g_alias=True)
    assert parser.feed(MANUAL_P_T) == []
    assert parser.stats.bad_checksum == 1


def test_corrected_twin_is_accepted() -> None:
    corrected = MANUAL_P_T[:-2] + bytes([0x05, 0x26])
    assert corrected == frame("P-T")
    assert Parser().feed(corrected) == [Telemetry(*MADRID)]


# ---------------------------------------------------------------- the G alias


def test_g_alias_decodes_the_manual_checksum_as_start_measuring() -> None:
    parser = Parser(accept_g_alias=True)
    [message] = parser.feed(P_G)
    assert message == StartMeasuring(*MADRID)
    assert type(message) is StartMeasuring
    assert parser.stats.errors == 0


def test_g_alias_is_off_by_default() -> None:
    parser = Parser()
    events = feed_and_close(parser, P_G)
    assert messages_of(events) == []
    assert parser.stats.unknown_type == 1
    assert events[0] == CorruptFrame(ErrorKind.UNKNOWN_TYPE, b"PG", events[0].detail)


def test_g_alias_is_only_for_the_autopilot() -> None:
    assert Parser(Sender.CC, accept_g_alias=True).feed(P_G) == []


def test_encode_can_send_the_g_byte() -> None:
    message = StartMeasuring(*MADRID)
    assert encode(message, start_type=AutopilotType.START_MEASURING_G) == P_G
    assert encode(message) == frame("P-M")


# ---------------------------------------------------------------- every case, several ways

CASES: list[tuple[str, bytes, Message, bool]] = [
    *((name, frame(name), message, False) for name, (_, message) in EXAMPLES.items()),
    ("P-G", P_G, StartMeasuring(*MADRID), True),
]
CASE_IDS = [case[0] for case in CASES]

LEADING_GARBAGE = [
    b"\x00",
    b"\xff\xfe\x13\x37",
    b"hello world\r\n",
    bytes(range(256)),  # every byte value, syncs included
    frame("P-T")[5:],  # the tail of a frame whose start was lost
]
STRAY_SYNCS = [b"P", b"R", b"PR", b"RP", b"PPRR", b"PT", b"PM", b"RM", b"PS", b"RO"]


@pytest.mark.parametrize(("name", "data", "expected", "alias"), CASES, ids=CASE_IDS)
def test_case_fed_whole(name: str, data: bytes, expected: Message, alias: bool) -> None:
    parser = Parser(accept_g_alias=alias)
    assert parser.feed(data) == [expected]
    assert parser.close() == []


@pytest.mark.parametrize(("name", "data", "expected", "alias"), CASES, ids=CASE_IDS)
def test_case_fed_one_byte_at_a_time(
    name: str, data: bytes, expected: Message, alias: bool
) -> None:
    parser = Parser(accept_g_alias=alias)
    outputs = [parser.feed(data[i : i + 1]) for i in range(len(data))]
    # Nothing until the last byte, then exactly the message.
    assert outputs == [[]] * (len(data) - 1) + [[expected]]
    assert parser.stats.bytes_received == len(data)


@pytest.mark.parametrize("garbage", LEADING_GARBAGE, ids=range(len(LEADING_GARBAGE)))
@pytest.mark.parametrize(("name", "data", "expected", "alias"), CASES, ids=CASE_IDS)
def test_case_after_leading_garbage(
    name: str, data: bytes, expected: Message, alias: bool, garbage: bytes
) -> None:
    whole = Parser(accept_g_alias=alias)
    assert messages_of(feed_and_close(whole, garbage + data)) == [expected]
    bytewise = Parser(accept_g_alias=alias)
    stream = garbage + data
    assert messages_of(
        feed_and_close(bytewise, *(stream[i : i + 1] for i in range(len(stream))))
    ) == [expected]
    assert bytewise.stats == whole.stats


@pytest.mark.parametrize("stray", STRAY_SYNCS)
@pytest.mark.parametrize(("name", "data", "expected", "alias"), CASES, ids=CASE_IDS)
def test_case_after_stray_sync_bytes(
    name: str, data: bytes, expected: Message, alias: bool, stray: bytes
) -> None:
    parser = Parser(accept_g_alias=alias)
    # A stray "PT" claims 25 bytes: a short frame after it is only settled by
    # more bytes or the end of the stream, so close() is part of the feed.
    events = feed_and_close(parser, stray + data)
    assert messages_of(events) == [expected]
    assert parser.stats.errors >= 1  # every stray start is reported
    assert parser.stats.frames_decoded == 1


@pytest.mark.parametrize("cut", [1, 2, 5, 7, 24])
@pytest.mark.parametrize(("name", "data", "expected", "alias"), CASES, ids=CASE_IDS)
def test_case_with_trailing_partial_frame(
    name: str, data: bytes, expected: Message, alias: bool, cut: int
) -> None:
    partial = frame("P-T")[:cut]  # no sync byte inside: one clean truncated report
    parser = Parser(accept_g_alias=alias)
    assert parser.feed(data + partial) == [expected]
    assert parser.pending == cut
    closing = parser.close()
    assert closing == [CorruptFrame(ErrorKind.TRUNCATED, partial, closing[0].detail)]
    assert parser.stats.truncated == 1
    assert parser.pending == 0
    assert parser.close() == []  # nothing left to report twice


@pytest.mark.parametrize(("name", "data", "expected", "alias"), CASES, ids=CASE_IDS)
def test_case_with_trailing_bytes_of_another_frame(
    name: str, data: bytes, expected: Message, alias: bool
) -> None:
    follow = frame("R-P")  # its type byte is "P": a sync byte inside a frame
    parser = Parser(accept_g_alias=alias)
    assert parser.feed(data + follow[:5]) == [expected]
    assert parser.feed(follow[5:]) == [ProbePosition(72, 4776)]
    assert parser.stats.errors == 0


# ---------------------------------------------------------------- corrupt cases, several ways


def _frame_with_checksum(body: bytes) -> bytes:
    return body + (sum(body) % 65536).to_bytes(2, "big")


BAD_SIGN = _frame_with_checksum(frame("P-T")[:4] + b"\x02" + frame("P-T")[5:-2])
CORRUPT: list[tuple[str, bytes, ErrorKind]] = [
    ("manual P-T", MANUAL_P_T, ErrorKind.BAD_CHECKSUM),
    ("R-M flipped bit", frame("R-M")[:5] + b"\xcd" + frame("R-M")[6:], ErrorKind.BAD_CHECKSUM),
    ("lon sign 02", BAD_SIGN, ErrorKind.BAD_FIELD),
    ("type X", b"PX", ErrorKind.UNKNOWN_TYPE),
]


@pytest.mark.parametrize(("label", "bad", "kind"), CORRUPT, ids=[c[0] for c in CORRUPT])
@pytest.mark.parametrize("way", ["whole", "bytewise", "after garbage"])
def test_corrupt_frame_is_counted_once_and_the_next_frame_survives(
    label: str, bad: bytes, kind: ErrorKind, way: str
) -> None:
    stream = (b"\x00\x11" if way == "after garbage" else b"") + bad + frame("R-P")
    chunks = [stream[i : i + 1] for i in range(len(stream))] if way == "bytewise" else [stream]
    seen: list[CorruptFrame] = []
    parser = Parser(on_error=seen.append)
    events = feed_and_close(parser, *chunks)
    assert messages_of(events) == [ProbePosition(72, 4776)]
    assert [error.kind for error in seen] == [kind]
    assert seen[0].data == (bad if kind is not ErrorKind.UNKNOWN_TYPE else b"PX")
    assert parser.stats.errors == 1
