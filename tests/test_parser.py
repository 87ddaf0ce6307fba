"""The streaming parser: chunking, resynchronisation, statistics, bounds, senders, end of stream.

The Hypothesis properties check the parser against `strategies.model_events`,
the resynchronisation rule written plainly over a whole stream, and then check
what that rule promises: a valid frame is lost only when garbage in front of
it forms a valid frame that overlaps it.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from cc_daemon.core.protocol import (
    Ack,
    CorruptFrame,
    ErrorKind,
    Message,
    Parser,
    ProbePosition,
    ProbePositionRequest,
    Sender,
    StartMeasuring,
    Telemetry,
    encode,
)
from cc_daemon.ground.logsetup import configure_logging
from tests import strategies as cs
from tests.test_protocol_examples import EXAMPLES, MANUAL_P_T, frame

MAX_FRAME = 26
# Streams of a few hundred bytes, some fed byte by byte: quick, but the suite
# shares two cores with subprocess tests, and a slow example is not a bug.
relaxed = settings(deadline=None)

Event = Message | CorruptFrame


def as_comparable(events: list[Event]) -> list[Message | tuple[str, bytes]]:
    return [
        (str(e.kind), e.data) if isinstance(e, CorruptFrame) else e  # errors by kind and bytes
        for e in events
    ]


def model_comparable(events: list[cs.ModelEvent]) -> list[Message | tuple[str, bytes]]:
    return [(e.result, e.data) if isinstance(e.result, str) else e.result for e in events]


def check_invariants(parser: Parser, decoded_bytes: int) -> None:
    stats = parser.stats
    assert stats.bytes_received == decoded_bytes + stats.bytes_discarded + parser.pending
    assert parser.pending < MAX_FRAME


def run_events(parser: Parser, chunks: list[bytes]) -> list[Event]:
    """Feed `chunks` through `events`, checking the invariants after each; then close."""
    out: list[Event] = []
    for chunk in chunks:
        out += parser.events(chunk)
        check_invariants(parser, sum(len(encode_any(e)) for e in out if is_message(e)))
    out += parser.close()
    check_invariants(parser, sum(len(encode_any(e)) for e in out if is_message(e)))
    assert parser.pending == 0
    return out


def run_feed(parser: Parser, chunks: list[bytes]) -> list[Message]:
    """Feed `chunks` through `feed` (its own fast path), then close."""
    out: list[Message] = []
    for chunk in chunks:
        out += parser.feed(chunk)
        check_invariants(parser, sum(len(encode_any(m)) for m in out))
    return out + [e for e in parser.close() if not isinstance(e, CorruptFrame)]


def is_message(e: Event) -> bool:
    return not isinstance(e, CorruptFrame)


def encode_any(message: Event) -> bytes:
    assert not isinstance(message, CorruptFrame)
    return encode(message)


@st.composite
def noisy_streams(draw: st.DrawFn) -> tuple[bytes, list[tuple[int, bytes, Message]]]:
    """Valid frames with garbage around them: (stream, [(offset, frame, message)]).
    A quarter of the frames follow garbage built to swallow their first bytes."""
    pieces: list[bytes] = []
    frames: list[tuple[int, bytes, Message]] = []
    offset = 0
    for message in draw(st.lists(cs.messages, max_size=8)):
        data = encode(message)
        noise = draw(cs.garbage)
        if draw(st.integers(0, 3)) == 0:
            noise += draw(cs.frame_eaters(data))
        frames.append((offset + len(noise), data, message))
        pieces += [noise, data]
        offset += len(noise) + len(data)
    return b"".join(pieces) + draw(cs.garbage), frames


# ---------------------------------------------------------------- properties


@relaxed
@given(st.lists(cs.messages, max_size=20), st.data())
def test_any_chunking_of_a_valid_stream_yields_the_same_messages(
    messages: list[Message], data: st.DataObject
) -> None:
    stream = b"".join(map(encode, messages))
    chunks = data.draw(cs.split(stream))
    parser = Parser()
    assert run_feed(parser, chunks) == messages
    assert parser.stats.frames_decoded == len(messages)
    assert parser.stats.errors == 0
    assert parser.stats.bytes_discarded == 0
    assert parser.stats.bytes_received == len(stream)


# Found by hypothesis: a firmware (26-byte) M whose last checksum byte is a sync
# byte; the model once resumed after 25 bytes and saw a truncated frame there.
FIRMWARE_M_ENDING_IN_P = b"PM" + bytes(12) + b"\x01\xf69\x00\x02\xadZ\x17d\xff\x04P"


def test_a_firmware_m_ending_in_a_sync_byte_is_one_frame_to_parser_and_model() -> None:
    [event] = cs.model_events(FIRMWARE_M_ENDING_IN_P, Sender.AUTOPILOT)
    assert isinstance(event.result, StartMeasuring) and event.result.mode == 255
    for split in ([FIRMWARE_M_ENDING_IN_P], [FIRMWARE_M_ENDING_IN_P[:25], b"P"]):
        assert as_comparable(run_events(Parser(Sender.AUTOPILOT), split)) == [event.result]


@relaxed
@given(noisy_streams(), cs.senders, st.booleans(), st.data())
def test_parser_follows_the_resynchronisation_rule(
    noisy: tuple[bytes, list[tuple[int, bytes, Message]]],
    senders: Sender,
    alias: bool,
    data: st.DataObject,
) -> None:
    stream = noisy[0]
    expected = cs.model_events(stream, senders, accept_g_alias=alias)
    # events(): every frame and every error, in stream order, whatever the chunking.
    parser = Parser(senders, accept_g_alias=alias)
    assert as_comparable(run_events(parser, data.draw(cs.split(stream)))) == model_comparable(
        expected
    )
    stats = parser.stats
    kinds = [e.result for e in expected if isinstance(e.result, str)]
    assert stats.frames_decoded == len(expected) - len(kinds)
    assert (stats.bad_checksum, stats.unknown_type, stats.bad_field, stats.truncated) == (
        kinds.count("bad_checksum"),
        kinds.count("unknown_type"),
        kinds.count("bad_field"),
        kinds.count("truncated"),
    )
    # feed(): the same messages through its own path, on another chunking.
    other = Parser(senders, accept_g_alias=alias)
    assert run_feed(other, data.draw(cs.split(stream))) == [
        e.result for e in expected if not isinstance(e.result, str)
    ]
    assert other.stats == stats


@relaxed
@given(noisy_streams(), st.data())
def test_valid_frames_in_garbage_are_recovered_unless_a_garbage_frame_overlaps_them(
    noisy: tuple[bytes, list[tuple[int, bytes, Message]]], data: st.DataObject
) -> None:
    stream, originals = noisy
    parser = Parser()
    decoded = run_feed(parser, data.draw(cs.split(stream)))
    # Where each decoded frame sits (the model, checked against the parser above).
    found = [
        (e.offset, e.data, e.result)
        for e in cs.model_events(stream)
        if not isinstance(e.result, str)
    ]
    assert [message for _, _, message in found] == decoded
    spans = {(offset, data_) for offset, data_, _ in found}
    for offset, data_, message in originals:
        if (offset, data_) in spans:
            continue
        # Lost: only because a valid frame that started earlier covers its start.
        culprits = [(o, d) for o, d, _ in found if o < offset < o + len(d)]
        assert culprits, f"{message!r} at {offset} lost with no overlapping frame"
        original_starts = {o for o, _, _ in originals}
        assert all(o not in original_starts for o, _ in culprits)  # born in the garbage
        event("an original frame was eaten by a valid frame in the garbage")
    # Every extra message is a frame that is really in the bytes.
    original_spans = {(offset, data_) for offset, data_, _ in originals}
    for offset, data_, message in found:
        assert stream[offset : offset + len(data_)] == data_
        if (offset, data_) not in original_spans:
            assert cs.model_frame(data_, type(message)) == message
            event("garbage formed a valid frame")
    if all((offset, data_) in spans for offset, data_, _ in originals):
        it = iter(decoded)
        assert all(any(m == message for m in it) for _, _, message in originals)


@relaxed
@given(st.lists(st.tuples(cs.sync_free_garbage, cs.messages), max_size=10), cs.sync_free_garbage)
def test_garbage_without_sync_bytes_costs_nothing_but_its_bytes(
    pairs: list[tuple[bytes, Message]], tail: bytes
) -> None:
    stream = b"".join(noise + encode(message) for noise, message in pairs) + tail
    for chunks in ([stream], [stream[i : i + 1] for i in range(len(stream))]):
        parser = Parser()
        assert run_feed(parser, chunks) == [message for _, message in pairs]
        assert parser.stats.errors == 0
        assert parser.stats.bytes_discarded == sum(len(noise) for noise, _ in pairs) + len(tail)


@relaxed
@given(st.binary(max_size=600), cs.senders, st.booleans(), st.data())
def test_arbitrary_bytes_never_raise(
    stream: bytes, senders: Sender, alias: bool, data: st.DataObject
) -> None:
    parser = Parser(senders, accept_g_alias=alias)
    events = run_events(parser, data.draw(cs.split(stream)))
    assert parser.stats.errors == sum(isinstance(e, CorruptFrame) for e in events)
    assert parser.stats.bytes_received == len(stream)


@relaxed
@given(st.lists(st.sampled_from([b"P", b"R", b"PT", b"PM", b"RM", b"\x00"]), max_size=300))
def test_sync_heavy_noise_never_raises_and_matches_the_rule(pieces: list[bytes]) -> None:
    stream = b"".join(pieces)
    parser = Parser()
    assert as_comparable(run_events(parser, [stream])) == model_comparable(cs.model_events(stream))


# ---------------------------------------------------------------- resynchronisation, by example


def test_a_frame_starting_inside_a_corrupt_frame_is_found() -> None:
    ack = frame("R-O")
    # "PT" claims 25 bytes; they do not check out, and the R-O inside them is found.
    stream = b"PT" + ack + bytes(17)
    parser = Parser()
    assert parser.feed(stream) == [Ack(72)]
    assert parser.stats.bad_checksum == 1


def test_a_frame_inside_a_frame_cut_by_the_end_of_the_stream_is_found() -> None:
    ack = frame("R-O")
    parser = Parser()
    assert parser.feed(b"PT" + ack) == []  # still could be a P-T
    assert parser.pending == 8
    events = parser.close()
    assert events == [CorruptFrame(ErrorKind.TRUNCATED, b"PT" + ack, events[0].detail), Ack(72)]
    assert parser.stats.truncated == 1
    assert parser.stats.frames_decoded == 1
    assert parser.stats.bytes_discarded == 2


def test_garbage_that_forms_a_valid_frame_eats_the_start_of_the_next() -> None:
    # 52 4F 00 AF is an R-O whose checksum 0x0150 ends in the P-S's sync byte:
    # the garbage and the first byte of the real frame make a valid frame.
    garbage = bytes.fromhex("52 4F 00 AF 01")
    stream = garbage + frame("P-S")
    parser = Parser()
    assert run_feed(parser, [stream]) == [Ack(0xAF)]  # the P-S is lost...
    assert parser.stats.bytes_discarded == len(frame("P-S")) - 1
    # ...and the model agrees: no parser could have both.
    assert [e.result for e in cs.model_events(stream)] == [Ack(0xAF)]


def test_unknown_type_after_a_sync_byte_is_counted_and_skipped() -> None:
    parser = Parser()
    seen: list[CorruptFrame] = []
    parser.on_error = seen.append
    assert parser.feed(b"PXRZ" + frame("P-S")) == [ProbePositionRequest(72)]
    assert [(e.kind, e.data) for e in seen] == [
        (ErrorKind.UNKNOWN_TYPE, b"PX"),
        (ErrorKind.UNKNOWN_TYPE, b"RZ"),
    ]
    assert parser.stats.unknown_type == 2
    assert parser.stats.bytes_discarded == 4


def test_corrupt_frames_are_logged_at_debug_with_their_bytes_by_the_daemons_setup() -> None:
    out = io.StringIO()
    configure_logging("json", "debug", out)
    parser = Parser()
    parser.feed(MANUAL_P_T + b"PX")
    parser.close()
    logs = [json.loads(line) for line in out.getvalue().splitlines()]
    assert [(e["level"], e["logger"], e["event"], e["kind"], e["bytes"]) for e in logs] == [
        (
            "debug",
            "cc_daemon.protocol",
            "corrupt frame",
            "bad_checksum",
            MANUAL_P_T.hex(" ").upper(),
        ),
        ("debug", "cc_daemon.protocol", "corrupt frame", "unknown_type", "50 58"),
    ]


def test_corrupt_frames_are_not_logged_above_debug() -> None:
    out = io.StringIO()
    configure_logging("json", "info", out)
    Parser().feed(MANUAL_P_T + b"PX")
    assert out.getvalue() == ""


def test_the_parser_as_a_library_is_silent_unless_logging_is_configured() -> None:
    # A fresh interpreter: nothing configured, as for any program importing the parser.
    code = (
        "from cc_daemon.core.protocol import Parser\n"
        f"p = Parser(); p.feed(bytes.fromhex({MANUAL_P_T.hex()!r}) + b'PX'); p.close()\n"
        "assert p.stats.errors == 2, p.stats\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=30, check=False
    )
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")


# ---------------------------------------------------------------- statistics and bounds


def test_stats_invariant_holds_after_every_call() -> None:
    stream = b"\x00PT" + MANUAL_P_T + frame("P-M") + b"R" + frame("R-F") + frame("P-T")[:9]
    parser = Parser()
    decoded = 0
    for i in range(0, len(stream), 3):
        decoded += sum(len(encode(m)) for m in parser.feed(stream[i : i + 3]))
        check_invariants(parser, decoded)
    assert parser.stats.frames_decoded == 2
    parser.close()
    check_invariants(parser, decoded)
    assert parser.stats.bytes_received == len(stream)


@pytest.mark.parametrize("size", [1, 7, 4096])
def test_buffer_stays_bounded_whatever_is_fed(size: int) -> None:
    # Endless starts of 25-byte frames, none ever completing a valid one.
    stream = (b"PT" + bytes(range(30))) * 200
    parser = Parser()
    for i in range(0, len(stream), size):
        parser.feed(stream[i : i + size])
        assert parser.pending < MAX_FRAME
    assert parser.stats.frames_decoded == 0


def test_counters_of_each_kind() -> None:
    bad_field = bytearray(frame("P-T"))
    bad_field[22] = 101  # confidence over 100
    bad_field[-2:] = (sum(bad_field[:-2]) % 65536).to_bytes(2, "big")
    parser = Parser()
    parser.feed(MANUAL_P_T + b"PQ" + bytes(bad_field) + frame("R-O") + b"RM\x00")
    parser.close()
    stats = parser.stats
    assert (stats.frames_decoded, stats.bad_checksum, stats.unknown_type, stats.bad_field) == (
        1,
        1,
        1,
        1,
    )
    assert stats.truncated == 1
    assert stats.errors == 4


# ---------------------------------------------------------------- senders

ALL_EXAMPLES = b"".join(bytes.fromhex(data) for data, _ in EXAMPLES.values())
AUTOPILOT_MESSAGES = [m for name, (_, m) in EXAMPLES.items() if name.startswith("P-")]
CC_MESSAGES = [m for name, (_, m) in EXAMPLES.items() if name.startswith("R-")]


@pytest.mark.parametrize(
    ("senders", "expected"),
    [
        (Sender.AUTOPILOT, AUTOPILOT_MESSAGES),
        (Sender.CC, CC_MESSAGES),
        (Sender.BOTH, AUTOPILOT_MESSAGES + CC_MESSAGES),
    ],
)
def test_a_parser_hears_only_the_senders_it_listens_to(
    senders: Sender, expected: list[Message]
) -> None:
    parser = Parser(senders)
    assert parser.feed(ALL_EXAMPLES) == expected


def test_an_autopilot_parser_ignores_cc_frames_without_counting_errors() -> None:
    # R frames carry no "P" here (R-P does: its type byte), so they are just bytes.
    stream = frame("R-O") + frame("P-S") + frame("R-M") + frame("R-F")
    parser = Parser(Sender.AUTOPILOT)
    assert parser.feed(stream) == [ProbePositionRequest(72)]
    assert parser.close() == []
    assert parser.stats.errors == 0


def test_the_cc_sync_byte_is_not_a_frame_start_for_the_autopilot_parser() -> None:
    parser = Parser(Sender.AUTOPILOT)
    assert parser.feed(b"R") == []
    assert parser.close() == []  # dropped, never reported as a truncated frame
    assert parser.stats.bytes_discarded == 1


# ---------------------------------------------------------------- feed, events, close


def test_events_and_feed_agree_and_errors_come_in_stream_order() -> None:
    stream = frame("P-T") + MANUAL_P_T + frame("R-O") + b"PX" + frame("R-P")
    events = Parser().events(stream)
    assert as_comparable(events) == [
        Telemetry(72, -37260579, 404506308, 702385, 8219, 100),
        ("bad_checksum", MANUAL_P_T),
        Ack(72),
        ("unknown_type", b"PX"),
        ProbePosition(72, 4776),
    ]
    assert Parser().feed(stream) == [e for e in events if is_message(e)]


def test_close_leaves_a_parser_ready_for_a_new_stream() -> None:
    parser = Parser()
    assert parser.feed(frame("P-M")[:10]) == []
    assert as_comparable(parser.close()) == [("truncated", frame("P-M")[:10])]
    assert parser.close() == []
    assert parser.feed(frame("P-M")) == [
        StartMeasuring(72, -37260579, 404506308, 702385, 8219, 100)
    ]


def test_close_on_a_lone_sync_byte_reports_it_truncated() -> None:
    parser = Parser()
    assert parser.feed(frame("R-O") + b"R") == [Ack(72)]
    assert parser.pending == 1
    assert as_comparable(parser.close()) == [("truncated", b"R")]


def test_timestamps_never_cause_a_frame_to_be_dropped() -> None:
    # Stuck at zero, jumping, going backwards: all frames arrive, in order.
    times = [0, 0, 65535, 3, 0, 40000, 1]
    stream = b"".join(encode(ProbePositionRequest(t)) for t in times)
    assert Parser().feed(stream) == [ProbePositionRequest(t) for t in times]


def test_the_properties_mix_both_lengths_of_m() -> None:
    # Guards the strategies: every property above runs on 25- and 26-byte M frames.
    from hypothesis import find

    assert len(encode(find(cs.start_measuring, lambda m: m.mode is None))) == 25
    assert len(encode(find(cs.start_measuring, lambda m: m.mode is not None))) == 26
