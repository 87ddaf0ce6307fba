"""The deployed firmware's bytes (UCM-237 serial_com.c, 2023), decoded as the daemon must.

Every fixture is a frame captured from the firmware's own code run against the
daemon (issue 8), used verbatim. Their timestamps are little-endian on the
wire; the parser reads the manual's big-endian and `cast.timestamps` turns it
into the autopilot's real clock (tested there).
"""

from __future__ import annotations

from typing import Any

import pytest
import structlog
from hypothesis import given
from hypothesis import strategies as st

from cc_daemon.cli.decode import decode_chunks, format_event
from cc_daemon.core.protocol import (
    CorruptFrame,
    ErrorKind,
    Parser,
    ProbeDown,
    ProbePositionRequest,
    ProbeUp,
    Sender,
    StartMeasuring,
    Telemetry,
    as_dict,
    encode,
)
from tests import strategies as cs

M_26 = bytes.fromhex(
    "50 4D 16 00 01 02 38 25 50 00 18 1C 4D 60 00 09 EB 10 00 00 0F A0 5A 00 04 51"
)
T_1 = bytes.fromhex("50 54 01 00 01 02 38 25 50 00 18 1C 4D 60 00 09 EB 10 00 00 0F A0 5A 04 43")
T_301 = bytes.fromhex("50 54 2D 01 01 02 38 25 50 00 18 1C 4D 60 00 00 13 88 00 00 0F A0 5A 04 07")
S_76 = bytes.fromhex("50 53 4C 00 00 EF")
U_306 = bytes.fromhex("50 55 32 01 00 D8")

# Timestamps as the parser reads them (big-endian): 22 s little-endian is 0x1600.
M_26_MESSAGE = StartMeasuring(0x1600, -37234000, 404508000, 650000, 4000, 90, 0)


@pytest.fixture(autouse=True)
def _quiet() -> Any:
    with structlog.testing.capture_logs() as captured:
        yield captured


def test_the_fixtures_decode_to_the_values_of_the_run() -> None:
    parser = Parser(Sender.AUTOPILOT)
    m, t1, t301, s, u = parser.feed(M_26 + T_1 + T_301 + S_76 + U_306)
    assert m == M_26_MESSAGE
    assert (m.lon_deg, m.lat_deg, m.alt_m, m.sonar_distance_m) == (-3.7234, 40.4508, 650.0, 4.0)
    assert t1 == Telemetry(0x0100, -37234000, 404508000, 650000, 4000, 90)
    # Altitude -5 m: the firmware drops the sign byte, the magnitude arrives.
    assert t301 == Telemetry(0x2D01, -37234000, 404508000, 5000, 4000, 90)
    assert s == ProbePositionRequest(0x4C00)
    assert u == ProbeUp(0x3201)
    assert parser.stats.errors == 0
    assert parser.stats.bytes_discarded == 0


def test_the_26_byte_m_encodes_back_to_the_same_bytes() -> None:
    assert encode(M_26_MESSAGE) == M_26
    assert encode(M_26_MESSAGE._replace(mode=None)) == M_26[:23] + (sum(M_26[:23])).to_bytes(2)
    assert encode(ProbeUp(0x3201)) == U_306
    assert encode(ProbeDown(0x3201)) == b"PD" + U_306[2:4] + (sum(b"PD" + U_306[2:4])).to_bytes(2)


def test_the_26_byte_m_byte_by_byte_yields_exactly_one_m() -> None:
    parser = Parser(Sender.AUTOPILOT)
    out = []
    for i in range(len(M_26)):
        out += parser.events(M_26[i : i + 1])
    assert out == [M_26_MESSAGE]
    assert parser.close() == []
    assert parser.stats.errors == 0


@pytest.mark.parametrize("cut", range(1, len(M_26)))
def test_the_26_byte_m_split_anywhere_and_paused_yields_one_m(cut: int) -> None:
    parser = Parser(Sender.AUTOPILOT)
    # The line pauses after the cut (e.g. after byte 25): nothing may be judged yet.
    assert parser.events(M_26[:cut]) == []
    assert parser.stats.errors == 0
    assert parser.events(M_26[cut:]) == [M_26_MESSAGE]
    assert parser.stats.errors == 0 and parser.pending == 0


@pytest.mark.parametrize("garbage", [b"\x00\xff", b"PM", b"P", b"PMPM\x16", b"R", b"PT\x01\x00"])
def test_the_26_byte_m_after_garbage_yields_one_m(garbage: bytes) -> None:
    events = list(decode_chunks([garbage + M_26 + S_76]))
    messages = [e for e in events if not isinstance(e, CorruptFrame)]
    assert messages == [M_26_MESSAGE, ProbePositionRequest(0x4C00)]


def test_a_26_byte_m_is_never_a_25_byte_bad_frame_plus_garbage() -> None:
    events = list(decode_chunks([M_26, T_1]))
    assert events == [M_26_MESSAGE, Telemetry(0x0100, -37234000, 404508000, 650000, 4000, 90)]


def test_a_corrupt_26_byte_m_is_reported_whole_and_a_frame_inside_it_found() -> None:
    corrupt = bytearray(M_26)
    corrupt[10] ^= 0x40
    corrupt[12:18] = S_76  # a valid P-S inside the broken M
    parser = Parser(Sender.AUTOPILOT)
    events = parser.events(bytes(corrupt)) + parser.close()
    assert events[0] == CorruptFrame(
        ErrorKind.BAD_CHECKSUM,
        bytes(corrupt),
        events[0].detail,  # type: ignore[union-attr]
    )
    assert "as 26 bytes" in events[0].detail  # type: ignore[union-attr]
    assert ProbePositionRequest(0x4C00) in events


def test_a_25_byte_m_with_a_bad_checksum_at_the_end_of_the_stream_is_a_bad_checksum() -> None:
    parser = Parser(Sender.AUTOPILOT)
    assert parser.events(M_26[:25]) == []  # waiting for a possible 26th byte
    [error, *_] = parser.close()
    assert isinstance(error, CorruptFrame)
    assert (error.kind, error.data) == (ErrorKind.BAD_CHECKSUM, M_26[:25])


def test_the_manuals_25_byte_m_still_decodes_without_a_mode() -> None:
    manual = bytes.fromhex(
        "50 4D 00 48 01 02 38 8D 23 00 18 1C 46 C4 00 0A B7 B1 00 00 20 1B 64 05 1F"
    )
    [message] = Parser().feed(manual)
    assert isinstance(message, StartMeasuring) and message.mode is None
    assert "mode" not in as_dict(message)


def test_decode_shows_the_mode_byte_and_the_stick_frames() -> None:
    lines = [format_event(e, as_json=False) for e in decode_chunks([M_26, U_306])]
    assert lines[0].startswith("P-M timestamp_s=5632 ") and " mode=0" in lines[0]
    assert lines[1] == "P-U timestamp_s=12801"


@given(st.lists(st.one_of(cs.start_measuring, cs.telemetry, cs.probe_ups, cs.probe_downs)))
def test_25_and_26_byte_m_frames_mixed_round_trip(messages: list[Any]) -> None:
    stream = b"".join(encode(m) for m in messages)
    parser = Parser(Sender.AUTOPILOT)
    assert list(parser.events(stream) + parser.close()) == messages


def test_a_tie_between_the_two_readings_goes_to_the_manuals_25_bytes() -> None:
    # Only a non-zero mode byte can make a 26-byte M check out as 25 bytes too:
    # bytes 0-22 summing to 0x0404 with mode 4 (checksum 0x0408) is such a frame.
    body = bytearray(M_26[:23])
    body[22] -= sum(body) - 0x0404  # the confidence byte: 90 % becomes 13 %
    frame = bytes(body) + bytes((4,)) + (0x0404 + 4).to_bytes(2)
    assert cs.reads_as_25_bytes(frame)
    m, *rest = Parser(Sender.AUTOPILOT).events(frame)
    assert isinstance(m, StartMeasuring) and m.mode is None and m.sonar_confidence_pct == 13
    assert rest == []  # the 26th byte (0x08) is not a sync byte: dropped silently
