"""The Ping1D codec over brping and the sonar module's state machine, sans-IO."""

from __future__ import annotations

import pytest
from brping import PingParser, definitions
from hypothesis import given
from hypothesis import strategies as st

from cc_daemon.core.errors import FieldError
from cc_daemon.drivers.sonar import ping
from cc_daemon.drivers.sonar.client import SonarClient, start_requests, stop_request
from cc_daemon.drivers.sonar.ping import (
    PING1D_TABLE,
    BadFrame,
    DistanceSimple,
    OtherMessage,
    PingStream,
    ProtocolVersion,
)

# The manual's request frames, tables 7.2, 7.7, 7.6, 7.4 and 7.5, byte for byte.
MANUAL_PROTOCOL_VERSION = bytes.fromhex("42 52 02 00 06 00 00 00 05 00 A1 00")
MANUAL_DEVICE_ID = bytes.fromhex("42 52 02 00 06 00 00 01 B1 04 52 01")
MANUAL_SPEED_OF_SOUND = bytes.fromhex("42 52 02 00 06 00 00 01 B3 04 54 01")
MANUAL_DISTANCE_SIMPLE = bytes.fromhex("42 52 02 00 06 00 00 01 BB 04 5C 01")
MANUAL_STREAM_START = bytes.fromhex("42 52 02 00 78 05 00 01 BB 04 D3 01")
MANUAL_STREAM_STOP = bytes.fromhex("42 52 02 00 79 05 00 01 BB 04 D4 01")


def _parse_all(parser: PingParser, data: bytes) -> list[object]:
    found = []
    for byte in data:
        if parser.parse_byte(byte) == PingParser.NEW_MESSAGE:
            found.append(parser.rx_msg)
    return found


def test_brping_default_table_loses_the_ping1d_distance_and_ours_does_not() -> None:
    frame = ping.encode(ping.DISTANCE_SIMPLE, src=1, distance=8219, confidence=93)
    [default] = _parse_all(PingParser(), frame)
    assert default.name == "altitude"  # the S500's message with the same id
    assert not hasattr(default, "distance") and not hasattr(default, "confidence")
    [ours] = _parse_all(PingParser(payload_dict=PING1D_TABLE), frame)
    assert (ours.name, ours.distance, ours.confidence) == ("distance_simple", 8219, 93)
    [event] = PingStream().feed(frame)
    assert event.event == DistanceSimple(8219, 93) and (event.src, event.dst) == (1, 0)


def test_the_module_sends_the_manuals_requests_byte_for_byte() -> None:
    assert ping.request(ping.PROTOCOL_VERSION, dst=0) == MANUAL_PROTOCOL_VERSION
    assert ping.request(ping.DISTANCE_SIMPLE) == MANUAL_DISTANCE_SIMPLE
    assert start_requests() == (
        MANUAL_PROTOCOL_VERSION + MANUAL_DEVICE_ID + MANUAL_SPEED_OF_SOUND + MANUAL_STREAM_START
    )
    assert stop_request() == MANUAL_STREAM_STOP


def test_the_manuals_reply_ids_are_not_the_devices() -> None:
    # Tables 7.8-7.11 give ids 4, 3, 2 and 5; a Ping1D answers with the ids it was asked for.
    assert definitions.PING1D_DISTANCE_SIMPLE == 1211
    assert definitions.COMMON_PROTOCOL_VERSION == 5
    assert definitions.PING1D_SPEED_OF_SOUND == 1203
    assert definitions.PING1D_DEVICE_ID == 1201
    assert PING1D_TABLE[4]["name"] == "device_information"  # not distance_simple


def test_encode_refuses_unknown_ids_and_fields() -> None:
    with pytest.raises(FieldError, match="message_id"):
        ping.encode(9999)
    with pytest.raises(FieldError, match="altitude_mm"):
        ping.encode(ping.DISTANCE_SIMPLE, altitude_mm=1)


def _reading(distance: int = 4000, confidence: int = 90) -> bytes:
    return ping.encode(ping.DISTANCE_SIMPLE, src=1, distance=distance, confidence=confidence)


def test_stream_resyncs_after_a_bad_checksum_from_the_byte_after_the_failed_b() -> None:
    good = _reading(1234, 77)
    # A frame cut short: its "checksum" is the next frame's first bytes. brping
    # alone would resume after the bytes it took and lose the good frame too.
    cut = good[:-3]
    stream = PingStream()
    events = [e.event for e in stream.feed(cut + good)]
    assert events[-1] == DistanceSimple(1234, 77)
    assert any(isinstance(e, BadFrame) for e in events)
    assert stream.errors >= 1


def test_stream_drops_an_absurd_length_at_once_and_keeps_bb() -> None:
    stream = PingStream()
    events = [e.event for e in stream.feed(b"BR\xff\xff" + b"B" + _reading(5, 6))]
    assert events == [
        BadFrame("payload length 65535 too long", b"BR\xff\xff"),
        DistanceSimple(5, 6),
    ]


def test_stream_reports_a_valid_unknown_message_without_printing(
    capsys: pytest.CaptureFixture[str],
) -> None:
    frame = bytearray(b"BR\x01\x00\x0f\x27\x01\x00\x07")  # id 9999, one payload byte
    total = sum(frame)
    frame += bytes([total & 0xFF, total >> 8])
    [event] = PingStream().feed(bytes(frame))
    assert event.event == OtherMessage(9999)
    assert capsys.readouterr().out == ""


@given(st.lists(st.binary(max_size=40), max_size=20), st.integers(0, 20))
def test_garbage_around_a_reading_never_raises_and_the_reading_survives(
    junk: list[bytes], split: int
) -> None:
    noise = b"".join(junk).replace(b"B", b"b")  # no false starts: the reading must come out
    data = noise + _reading(4321, 88) + noise
    stream = PingStream()
    events = stream.feed(data[:split]) + stream.feed(data[split:])
    assert [e.event for e in events if isinstance(e.event, DistanceSimple)] == [
        DistanceSimple(4321, 88)
    ]


@given(st.binary(max_size=300))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    PingStream().feed(data)


def test_client_keeps_the_latest_reading_and_ages_it_to_confidence_zero() -> None:
    client = SonarClient(max_age_s=1.0)
    assert client.reading(0.0).confidence_pct == 0  # nothing heard yet
    hello = ping.encode(
        ping.PROTOCOL_VERSION, src=1, version_major=1, version_minor=2, version_patch=3
    )
    client.feed(0.0, hello + ping.encode(ping.DEVICE_ID, src=1, device_id=1))
    client.feed(0.0, ping.encode(ping.SPEED_OF_SOUND, src=1, speed_of_sound=1_450_000))
    assert (client.protocol_version, client.device_id, client.speed_of_sound_mm_s) == (
        (1, 2, 3),
        1,
        1_450_000,
    )
    assert [r.distance_mm for r in client.feed(10.0, _reading(4000, 90))] == [4000]
    client.feed(10.25, _reading(4100, 95))
    assert client.reading(11.0) == client.latest
    assert (client.reading(11.0).distance_mm, client.reading(11.0).confidence_pct) == (4100, 95)
    stale = client.reading(11.3)
    assert (stale.distance_mm, stale.confidence_pct) == (4100, 0)


def test_client_restarts_a_silent_stream_and_not_a_talking_one() -> None:
    client = SonarClient(restart_after_s=3.0)
    assert client.poll(0.0) == b""  # not started: nothing to do
    assert client.start(0.0) == start_requests()
    assert client.poll(2.9) == b""
    assert client.poll(3.0) == start_requests()  # a power-cycled Ping forgot the stream
    for t in (3.5, 4.0, 4.5, 5.0, 5.5, 6.0, 6.5):
        client.feed(t, _reading())
        assert client.poll(t) == b""
    assert client.poll(9.5) == start_requests()
    assert client.stop() == stop_request()
    assert client.poll(100.0) == b""
    assert client.starts == 3


def test_client_counts_bad_frames_and_reads_on() -> None:
    client = SonarClient()
    bad = bytearray(_reading(1, 1))
    bad[9] ^= 0x10
    readings = client.feed(0.0, bytes(bad) + _reading(2, 2))
    assert [r.distance_mm for r in readings] == [2]
    assert client.bad_frames == 1


def test_client_rejects_nonsense_settings() -> None:
    with pytest.raises(ValueError, match="max_age_s"):
        SonarClient(max_age_s=0)
    with pytest.raises(ValueError, match="restart_after_s"):
        SonarClient(restart_after_s=-1)


def test_protocol_version_reply_decodes() -> None:
    reply = ping.encode(
        ping.PROTOCOL_VERSION, src=1, version_major=1, version_minor=0, version_patch=0
    )
    [event] = PingStream().feed(reply)
    assert event.event == ProtocolVersion(1, 0, 0)


@given(st.lists(st.integers(1, 30), max_size=10), st.integers(0, 3))
def test_any_chunking_gives_the_same_events(cuts: list[int], garbage: int) -> None:
    data = b"\x00B" * garbage + _reading(1, 2) + b"BR\x05" + _reading(3, 4) + _reading(5, 6)
    whole = PingStream().feed(data)
    stream = PingStream()
    chunked = []
    rest = data
    for cut in cuts:
        chunked += stream.feed(rest[:cut])
        rest = rest[cut:]
    chunked += stream.feed(rest)
    assert chunked == whole
    assert [e.event for e in whole if isinstance(e.event, DistanceSimple)] == [
        DistanceSimple(1, 2),
        DistanceSimple(3, 4),
        DistanceSimple(5, 6),
    ]
