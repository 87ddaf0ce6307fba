"""Messages as values, and the per-field wire rules of encode and decode.

Frames here are built by hand (`position_frame`) from PROTOCOL.md's offsets
with their own checksum, so the field rules are checked independently of
`frames.py`'s struct layouts.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cc_daemon.core.errors import FieldError, ProtocolError
from cc_daemon.core.protocol import (
    MESSAGE_TYPES,
    Ack,
    AutopilotType,
    CorruptFrame,
    DepthReport,
    ErrorKind,
    Finished,
    Message,
    Parser,
    ProbeDown,
    ProbePosition,
    ProbePositionRequest,
    ProbeUp,
    Sender,
    StartMeasuring,
    Telemetry,
    as_dict,
    encode,
)
from tests import strategies as cs

MADRID = (72, -37260579, 404506308, 702385, 8219, 100)


def with_checksum(body: bytes) -> bytes:
    return body + (sum(body) % 65536).to_bytes(2, "big")


def position_frame(
    *,
    type_byte: bytes = b"T",
    timestamp: int = 72,
    lon: tuple[int, int] = (1, 37260579),
    lat: tuple[int, int] = (0, 404506308),
    alt: tuple[int, int] = (0, 702385),
    sonar: int = 8219,
    confidence: int = 100,
) -> bytes:
    """A P-T/P-M frame from (sign byte, magnitude) pairs, checksum included."""
    return with_checksum(
        b"P"
        + type_byte
        + timestamp.to_bytes(2, "big")
        + bytes([lon[0]])
        + lon[1].to_bytes(4, "big")
        + bytes([lat[0]])
        + lat[1].to_bytes(4, "big")
        + bytes([alt[0]])
        + alt[1].to_bytes(3, "big")
        + sonar.to_bytes(4, "big")
        + bytes([confidence])
    )


def decode_one(data: bytes, **parser_args: Any) -> Any:
    """The single event (a message or a CorruptFrame) a lone frame produces."""
    parser = Parser(**parser_args)
    [result] = parser.events(data) + parser.close()
    return result


def sample_args(cls: type[Any]) -> tuple[int, ...]:
    """Valid fields after the timestamp for a message class."""
    if cls in (Telemetry, StartMeasuring):
        return MADRID[1:]
    if cls in (ProbePositionRequest, ProbeUp, ProbeDown, Ack):
        return ()
    return (7,)


def test_hand_built_frame_matches_the_manual_example() -> None:
    # Guards the helper itself: it must rebuild PROTOCOL.md's corrected P-T.
    assert position_frame() == bytes.fromhex(
        "50 54 00 48 01 02 38 8D 23 00 18 1C 46 C4 00 0A B7 B1 00 00 20 1B 64 05 26"
    )


# ---------------------------------------------------------------- round trips


@given(cs.messages)
def test_encode_then_decode_is_the_identity(message: Message) -> None:
    data = encode(message)
    parser = Parser()
    [decoded] = parser.feed(data)
    assert decoded == message
    assert type(decoded) is type(message)
    assert parser.stats.errors == 0
    # And an independent decoding of the same bytes agrees.
    assert cs.model_frame(data, type(message)) == message


@given(cs.messages)
def test_encoded_frames_follow_the_layout(message: Message) -> None:
    data = encode(message)
    sync, kind = message.frame.split("-")
    assert data[:2] == (sync + kind).encode()
    lengths = {"P-T": 25, "P-M": 25, "P-S": 6, "P-U": 6, "P-D": 6, "R-O": 6}
    firmware_m = isinstance(message, StartMeasuring) and message.mode is not None
    assert len(data) == (26 if firmware_m else lengths.get(message.frame, 8))
    assert int.from_bytes(data[2:4], "big") == message.timestamp_s
    assert int.from_bytes(data[-2:], "big") == sum(data[:-2]) % 65536


@given(cs.start_measuring)
def test_g_alias_round_trip(message: StartMeasuring) -> None:
    message = message._replace(mode=None)  # the G hint is the manual's 25-byte frame
    data = encode(message, start_type=AutopilotType.START_MEASURING_G)
    assert data[1:2] == b"G"
    assert Parser(Sender.AUTOPILOT, accept_g_alias=True).feed(data) == [message]


# ---------------------------------------------------------------- signed fields


@pytest.mark.parametrize("field", ["lon", "lat", "alt"])
@pytest.mark.parametrize("sign", [0x02, 0x10, 0x80, 0xFF])
def test_sign_byte_other_than_00_or_01_is_a_bad_field(field: str, sign: int) -> None:
    magnitudes = {"lon": 37260579, "lat": 404506308, "alt": 702385}
    data = position_frame(**{field: (sign, magnitudes[field])})
    result = decode_one(data)
    assert result == CorruptFrame(ErrorKind.BAD_FIELD, data, result.detail)
    assert field in result.detail


def test_signed_fields_are_sign_and_magnitude_not_twos_complement() -> None:
    message = Telemetry(72, -72, 72, -72, 0, 0)
    data = encode(message)
    assert data[4:9] == bytes.fromhex("01 00 00 00 48")  # -72 in 5 bytes, as the manual says
    assert data[9:14] == bytes.fromhex("00 00 00 00 48")
    assert data[14:18] == bytes.fromhex("01 00 00 48")  # altitude: sign + 3 bytes


def test_negative_altitude_from_the_firmware_decodes() -> None:
    # The firmware's sign-byte routine: 01 then a 3-byte magnitude.
    data = position_frame(alt=(1, 0x001234))
    result = decode_one(data)
    assert result == Telemetry(72, -37260579, 404506308, -0x1234, 8219, 100)
    assert isinstance(result, Telemetry)
    assert result.alt_m == pytest.approx(-4.66)


def test_largest_altitudes_decode() -> None:
    assert decode_one(position_frame(alt=(0, 0xFFFFFF))).alt_mm == 0xFFFFFF
    assert decode_one(position_frame(alt=(1, 0xFFFFFF))).alt_mm == -0xFFFFFF


@pytest.mark.parametrize(
    ("field", "value", "ok"),
    [
        ("lat", (0, 900_000_000), True),
        ("lat", (1, 900_000_000), True),
        ("lat", (0, 900_000_001), False),
        ("lat", (1, 900_000_001), False),
        ("lat", (0, 0xFFFFFFFF), False),
        ("lon", (0, 1_800_000_000), True),
        ("lon", (1, 1_800_000_000), True),
        ("lon", (0, 1_800_000_001), False),
        ("lon", (1, 0xFFFFFFFF), False),
    ],
)
def test_latitude_beyond_90_and_longitude_beyond_180_are_bad_fields(
    field: str, value: tuple[int, int], ok: bool
) -> None:
    result = decode_one(position_frame(**{field: value}))
    if ok:
        assert isinstance(result, Telemetry)
        degrees = getattr(result, f"{field}_deg")
        assert abs(degrees) == (90.0 if field == "lat" else 180.0)
    else:
        assert isinstance(result, CorruptFrame)
        assert result.kind is ErrorKind.BAD_FIELD


@pytest.mark.parametrize(("confidence", "ok"), [(0, True), (100, True), (101, False), (255, False)])
def test_confidence_over_100_is_a_bad_field(confidence: int, ok: bool) -> None:
    result = decode_one(position_frame(type_byte=b"M", confidence=confidence))
    if ok:
        assert result == StartMeasuring(72, -37260579, 404506308, 702385, 8219, confidence)
    else:
        assert isinstance(result, CorruptFrame)
        assert result.kind is ErrorKind.BAD_FIELD
        assert "confidence" in result.detail


def test_sonar_distance_uses_all_four_bytes() -> None:
    assert decode_one(position_frame(sonar=0xFFFFFFFF)).sonar_distance_mm == 0xFFFFFFFF


# ---------------------------------------------------------------- depth and timestamps on encode


@pytest.mark.parametrize(
    ("depth", "wire"), [(0, 0), (65534, 65534), (65535, 65535), (65536, 65535), (10**9, 65535)]
)
@pytest.mark.parametrize("cls", [DepthReport, Finished, ProbePosition])
def test_depth_saturates_at_65535_on_encode(cls: type[DepthReport], depth: int, wire: int) -> None:
    data = encode(cls(72, depth))
    assert int.from_bytes(data[4:6], "big") == wire
    assert Parser().feed(data) == [cls(72, wire)]


@given(st.integers(0, 2**48))
def test_depth_never_wraps(depth: int) -> None:
    assert Parser().feed(encode(DepthReport(1, depth))) == [DepthReport(1, min(depth, 65535))]


@given(st.integers(0, 2**48), st.sampled_from(MESSAGE_TYPES))
def test_timestamp_is_taken_modulo_65536_on_encode(timestamp: int, cls: type[Any]) -> None:
    args = sample_args(cls)
    assert Parser().feed(encode(cls(timestamp, *args))) == [cls(timestamp % 65536, *args)]


def test_timestamp_modulo_reproduces_the_manual_bytes() -> None:
    assert encode(Ack(72 + 65536)) == bytes.fromhex("52 4F 00 48 00 E9")
    assert encode(Telemetry(72 + 3 * 65536, *MADRID[1:]))[2:4] == b"\x00\x48"


# ---------------------------------------------------------------- construction


@pytest.mark.parametrize(
    ("build", "field"),
    [
        (lambda: Telemetry(-1, *MADRID[1:]), "timestamp_s"),
        (lambda: Telemetry(72, 1_800_000_001, *MADRID[2:]), "lon_e7"),
        (lambda: Telemetry(72, -1_800_000_001, *MADRID[2:]), "lon_e7"),
        (lambda: StartMeasuring(72, MADRID[1], 900_000_001, *MADRID[3:]), "lat_e7"),
        (lambda: StartMeasuring(72, MADRID[1], -900_000_001, *MADRID[3:]), "lat_e7"),
        (lambda: Telemetry(*MADRID[:3], 0x1000000, 8219, 100), "alt_mm"),
        (lambda: Telemetry(*MADRID[:3], -0x1000000, 8219, 100), "alt_mm"),
        (lambda: Telemetry(*MADRID[:4], -1, 100), "sonar_distance_mm"),
        (lambda: Telemetry(*MADRID[:4], 2**32, 100), "sonar_distance_mm"),
        (lambda: Telemetry(*MADRID[:5], 101), "sonar_confidence_pct"),
        (lambda: Telemetry(*MADRID[:5], -1), "sonar_confidence_pct"),
        (lambda: Telemetry(72, -3.7, *MADRID[2:]), "lon_e7"),  # degrees, not e7
        (lambda: Telemetry(72, *MADRID[1:5], True), "sonar_confidence_pct"),
        (lambda: ProbePositionRequest(-1), "timestamp_s"),
        (lambda: Ack("72"), "timestamp_s"),
        (lambda: DepthReport(72, -1), "depth_mm"),
        (lambda: Finished(72, 1.5), "depth_mm"),
        (lambda: ProbePosition(None, 0), "timestamp_s"),
    ],
)
def test_construction_validates_and_names_the_field(build: Any, field: str) -> None:
    with pytest.raises(FieldError) as caught:
        build()
    assert caught.value.field == field
    assert field in str(caught.value)
    assert isinstance(caught.value, ValueError)
    assert isinstance(caught.value, ProtocolError)


def test_construction_accepts_the_edges_of_every_range() -> None:
    Telemetry(0, 1_800_000_000, 900_000_000, 0xFFFFFF, 0xFFFFFFFF, 100)
    StartMeasuring(0, -1_800_000_000, -900_000_000, -0xFFFFFF, 0, 0)
    DepthReport(2**40, 2**40)  # open-ended: wrapped and saturated on encode


# ---------------------------------------------------------------- values


def test_equality_includes_the_message_type() -> None:
    assert DepthReport(72, 0) != Finished(72, 0)
    assert Finished(72, 0) != ProbePosition(72, 0)
    assert Ack(72) != ProbePositionRequest(72)
    assert Telemetry(*MADRID) != StartMeasuring(*MADRID)
    assert DepthReport(72, 0) == DepthReport(72, 0)
    assert not DepthReport(72, 0) != DepthReport(72, 0)  # noqa: SIM202 (tests __ne__ itself)
    assert DepthReport(72, 0) != (72, 0)
    assert len({DepthReport(72, 0), Finished(72, 0), DepthReport(72, 0)}) == 2


def test_messages_are_immutable() -> None:
    message = DepthReport(72, 100)
    with pytest.raises(AttributeError):
        message.depth_mm = 5  # type: ignore[misc]


def test_convenience_properties() -> None:
    telemetry = Telemetry(72, -37260579, 404506308, -702385, 8219, 100)
    assert telemetry.lon_deg == pytest.approx(-3.7260579)
    assert telemetry.lat_deg == pytest.approx(40.4506308)
    assert telemetry.alt_m == pytest.approx(-702.385)
    assert telemetry.sonar_distance_m == pytest.approx(8.219)
    assert DepthReport(72, 15820).depth_m == pytest.approx(15.82)
    assert ProbePosition(72, 4776).depth_m == pytest.approx(4.776)


def test_frame_names_and_dicts() -> None:
    assert [cls.frame for cls in MESSAGE_TYPES] == [
        "P-T",
        "P-M",
        "P-S",
        "P-U",
        "P-D",
        "R-O",
        "R-M",
        "R-F",
        "R-P",
        "R-L",
    ]
    assert as_dict(Finished(72, 0)) == {"frame": "R-F", "timestamp_s": 72, "depth_mm": 0}
    assert as_dict(Telemetry(*MADRID)) == {
        "frame": "P-T",
        "timestamp_s": 72,
        "lon_e7": -37260579,
        "lat_e7": 404506308,
        "alt_mm": 702385,
        "sonar_distance_mm": 8219,
        "sonar_confidence_pct": 100,
    }


def test_encode_rejects_what_is_not_a_message() -> None:
    with pytest.raises(TypeError):
        encode((72, 0))  # type: ignore[arg-type]
