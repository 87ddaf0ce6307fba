"""`Parser.events_in_runs`: P-T frames back to back checked together, as one run.

The run path must judge every frame exactly as the frame-at-a-time path does:
the properties compare it, expanded, with `strategies.model_events` (the
resynchronisation rule written plainly, with its own field checks) and with
`events`, on telemetry-heavy streams in which one frame of a run is broken in
each of the ways a frame can be (every check of `runs.run_length`), and on
any chunking. The examples pin each check at its boundary.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cc_daemon.core.protocol import (
    CorruptFrame,
    Message,
    Parser,
    ProbePositionRequest,
    Sender,
    Telemetry,
    TelemetryRun,
    encode,
    runs,
)
from tests import strategies as cs
from tests.test_parser import noisy_streams

relaxed = settings(deadline=None)

Event = Message | CorruptFrame | TelemetryRun


def fix(n: int, **fields: int) -> Telemetry:
    values = {
        "timestamp_s": n,
        "lon_e7": -37260579,
        "lat_e7": 404506308 + n,
        "alt_mm": 702385,
        "sonar_distance_mm": 8219,
        "sonar_confidence_pct": 100,
    } | fields
    return Telemetry(**values)


def resummed(body: bytes) -> bytes:
    """23 bytes of a P-T with the checksum they sum to: a frame whose only fault is
    in a field (or none)."""
    assert len(body) == 23
    return body + (sum(body) & 0xFFFF).to_bytes(2, "big")


def with_byte(frame: bytes, at: int, value: int) -> bytes:
    """`frame` with byte `at` set to `value`, checksum made right again."""
    body = bytearray(frame[:23])
    body[at] = value
    return resummed(bytes(body))


def with_u32(frame: bytes, at: int, value: int) -> bytes:
    body = bytearray(frame[:23])
    body[at : at + 4] = value.to_bytes(4, "big")
    return resummed(bytes(body))


# Every way one frame in a run can fail a check of `run_length`, and the
# boundary values that pass. (name, transform of a valid P-T frame)
BREAKS = {
    "checksum off by one": lambda f: f[:24] + bytes([(f[24] + 1) & 0xFF]),
    "checksum's high byte": lambda f: f[:23] + bytes([f[23] ^ 0x01]) + f[24:],
    "a field byte flipped, checksum not": lambda f: f[:7] + bytes([f[7] ^ 0x10]) + f[8:],
    "type byte M": lambda f: f[:1] + b"M" + f[2:],
    "type byte S": lambda f: f[:1] + b"S" + f[2:],
    "sync byte R": lambda f: b"R" + f[1:],
    "longitude sign 2": lambda f: with_byte(f, 4, 2),
    "latitude sign 0xFF": lambda f: with_byte(f, 9, 0xFF),
    "altitude sign 2": lambda f: with_byte(f, 14, 2),
    "confidence 101": lambda f: with_byte(f, 22, 101),
    "confidence 255": lambda f: with_byte(f, 22, 255),
    "longitude 180 degrees and a tenth-millionth": lambda f: with_u32(f, 5, 1_800_000_001),
    "longitude magnitude 0xFFFFFFFF": lambda f: with_u32(f, 5, 0xFFFFFFFF),
    "latitude 90 degrees and a tenth-millionth": lambda f: with_u32(f, 10, 900_000_001),
    "latitude top byte 0x35, over": lambda f: with_u32(f, 10, 0x35FFFFFF),
}
PASSES = {
    "longitude exactly 180 degrees": lambda f: with_u32(f, 5, 1_800_000_000),
    "longitude top byte 0x6B, in range": lambda f: with_u32(f, 5, 0x6B000000),
    "latitude exactly 90 degrees": lambda f: with_u32(f, 10, 900_000_000),
    "latitude top byte 0x35, in range": lambda f: with_u32(f, 10, 0x35000000),
    "confidence 100": lambda f: with_byte(f, 22, 100),
    "confidence 0, signs 1": lambda f: with_byte(with_byte(with_byte(f, 22, 0), 4, 1), 9, 1),
}


def expanded(events: list[Event]) -> list[Message | CorruptFrame]:
    out: list[Message | CorruptFrame] = []
    for event in events:
        if isinstance(event, TelemetryRun):
            assert len(event) >= 2
            out.extend(event)
        else:
            out.append(event)
    return out


def comparable(events: list[Message | CorruptFrame]) -> list[object]:
    return [(str(e.kind), e.data) if isinstance(e, CorruptFrame) else e for e in events]


def in_runs(parser: Parser, chunks: list[bytes]) -> list[Event]:
    out: list[Event] = []
    for chunk in chunks:
        out += parser.events_in_runs(chunk)
    return out + list(parser.close())


def one_by_one(parser: Parser, chunks: list[bytes]) -> list[Message | CorruptFrame]:
    out: list[Message | CorruptFrame] = []
    for chunk in chunks:
        out += parser.events(chunk)
    return out + parser.close()


@st.composite
def telemetry_streams(draw: st.DrawFn) -> bytes:
    """Runs of valid P-T (0 to 40), each maybe followed by a P-T broken one way,
    another frame or garbage: what a babbling autopilot sends, and its faults."""
    pieces: list[bytes] = []
    for _ in range(draw(st.integers(1, 5))):
        pieces += [encode(m) for m in draw(st.lists(cs.telemetry, max_size=40))]
        frame = encode(draw(cs.telemetry))
        tail = draw(st.sampled_from(["break", "pass", "other", "garbage", "none"]))
        if tail == "break":
            pieces.append(BREAKS[draw(st.sampled_from(sorted(BREAKS)))](frame))
        elif tail == "pass":
            pieces.append(PASSES[draw(st.sampled_from(sorted(PASSES)))](frame))
        elif tail == "other":
            pieces.append(encode(draw(cs.autopilot_messages)))
        elif tail == "garbage":
            pieces.append(draw(cs.garbage))
    return b"".join(pieces)


@relaxed
@given(telemetry_streams(), st.data())
def test_runs_expanded_are_the_model_and_events_on_any_chunking(
    stream: bytes, data: st.DataObject
) -> None:
    expected = cs.model_events(stream, Sender.AUTOPILOT)
    runs_parser = Parser(Sender.AUTOPILOT)
    got = in_runs(runs_parser, data.draw(cs.split(stream)))
    assert comparable(expanded(got)) == [
        (e.result, e.data) if isinstance(e.result, str) else e.result for e in expected
    ]
    frame_parser = Parser(Sender.AUTOPILOT)
    assert expanded(got) == one_by_one(frame_parser, data.draw(cs.split(stream)))
    assert runs_parser.stats == frame_parser.stats


# Runs are checked in windows of 8 frames, then 64...: breaks at the first
# frame, the second, inside and at the edges of the windows (8, 72), the last.
@pytest.mark.parametrize("name", sorted(BREAKS))
@pytest.mark.parametrize("where", [0, 1, 5, 7, 8, 9, 71, 72, 299])
def test_a_broken_frame_ends_the_run_and_is_judged_alone(name: str, where: int) -> None:
    frames = [encode(fix(n)) for n in range(300)]
    frames[where] = BREAKS[name](frames[where])
    stream = b"".join(frames)
    grouped, single = Parser(Sender.AUTOPILOT), Parser(Sender.AUTOPILOT)
    got = expanded(grouped.events_in_runs(stream) + grouped.close())
    assert got == single.events(stream) + single.close()
    assert grouped.stats == single.stats
    # Reported (an R frame is not an autopilot parser's to report: dropped unread),
    # with whatever its bytes look like as the parser resynchronises inside it.
    assert (grouped.stats.errors == 0) == (name == "sync byte R")
    assert [m.timestamp_s for m in got if isinstance(m, Telemetry)] == [
        n for n in range(300) if n != where
    ]


@pytest.mark.parametrize("name", sorted(PASSES))
def test_values_at_the_edge_of_range_stay_in_the_run(name: str) -> None:
    frames = [encode(fix(n)) for n in range(6)]
    frames[3] = PASSES[name](frames[3])
    [run] = Parser(Sender.AUTOPILOT).events_in_runs(b"".join(frames))
    assert isinstance(run, TelemetryRun) and len(run) == 6
    assert run[3] == Parser(Sender.AUTOPILOT).events(frames[3])[0]


def test_frames_that_fail_are_not_checked_twice_and_runs_cost_their_length(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Frames failing one by one (bad checksums, good frames alone between bad
    # ones) are never looked at as runs; a run is checked over a few times its
    # own length at most, never over the rest of the read for each run.
    examined: list[int] = []
    check = runs._valid_frames

    def counting(block: bytes, count: int) -> int:
        examined.append(len(block))
        return check(block, count)

    monkeypatch.setattr(runs, "_valid_frames", counting)
    good = [encode(fix(n)) for n in range(400)]
    bad = b"PT" + bytes(23)
    lone = b"".join(frame + bad for frame in good[:100])  # no run: no window checked
    runs_of_two = b"".join(good[n] + good[n + 1] + bad for n in range(0, 200, 2))
    for stream, windows in ((bad * 100, 0), (lone, 0), (runs_of_two, 100), (b"".join(good), 3)):
        examined.clear()
        got = Parser(Sender.AUTOPILOT).events_in_runs(stream)
        assert expanded(got) == Parser(Sender.AUTOPILOT).events(stream)
        assert len(examined) == windows
        assert sum(examined) <= 16 * len(stream)  # runs of two: one 8-frame window each
    assert examined == [8 * 25, 64 * 25, 328 * 25]  # 400 frames: 8, 64, the rest


def test_a_run_is_a_sequence_of_its_fixes_decoded_when_asked() -> None:
    fixes = [fix(n, sonar_distance_mm=1000 + n) for n in range(7)]
    parser = Parser(Sender.AUTOPILOT)
    [run] = parser.events_in_runs(b"".join(map(encode, fixes)))
    assert isinstance(run, TelemetryRun)
    assert (run.first, run.last, len(run)) == (fixes[0], fixes[-1], 7)
    assert list(run) == fixes
    assert (run[0], run[-1], run[3], run[-7]) == (fixes[0], fixes[-1], fixes[3], fixes[0])
    assert run[1:4] == fixes[1:4] and run[::-1] == fixes[::-1] and run[-1:] == fixes[-1:]
    for outside in (7, -8):
        with pytest.raises(IndexError):
            run[outside]
    assert parser.stats.frames_decoded == 7 and parser.stats.bytes_received == 7 * 25
    assert "7 P-T" in repr(run)


def test_a_lone_fix_and_a_frame_cut_by_the_read_are_not_runs() -> None:
    two = encode(fix(1)) + encode(fix(2))
    parser = Parser(Sender.AUTOPILOT)
    assert parser.events_in_runs(two[:40]) == [fix(1)]  # the second waits for its bytes
    assert parser.events_in_runs(two[40:]) == [fix(2)]
    request = encode(ProbePositionRequest(9))
    got = parser.events_in_runs(two + request + two + two[:30])
    assert [type(e) for e in got] == [TelemetryRun, ProbePositionRequest, TelemetryRun]
    assert parser.pending == 5


def test_only_an_autopilot_parser_makes_runs() -> None:
    stream = b"".join(encode(fix(n)) for n in range(5))
    assert Parser(Sender.CC).events_in_runs(stream) == []
    [run] = Parser(Sender.BOTH).events_in_runs(stream)
    assert isinstance(run, TelemetryRun) and len(run) == 5


def model_unframed(stream: bytes, senders: Sender) -> int:
    """Bytes in no frame the model decoded or reported corrupt: those no frame could
    start in (`ParserStats.bytes_unframed`)."""
    spanned: set[int] = set()
    for event in cs.model_events(stream, senders):
        spanned.update(range(event.offset, event.offset + len(event.data)))
    return len(stream) - len(spanned)


@relaxed
@given(
    st.one_of(telemetry_streams(), st.builds(lambda pair: pair[0], noisy_streams())),
    cs.senders,
    st.booleans(),
    st.data(),
)
def test_bytes_no_frame_could_start_in_are_counted_apart(
    stream: bytes, senders: Sender, grouped: bool, data: st.DataObject
) -> None:
    # The daemon's evidence of an M whose sync byte flipped (no corrupt frame says
    # so): never the rest of a corrupt frame the parser resynchronised through.
    parser = Parser(senders)
    feed = parser.events_in_runs if grouped else parser.events
    for chunk in data.draw(cs.split(stream)):
        feed(chunk)
    parser.close()
    assert parser.stats.bytes_unframed == model_unframed(stream, senders)


def test_a_corrupt_frame_is_not_also_unframed_bytes() -> None:
    good = encode(fix(1))
    bad = good[:24] + bytes([good[24] ^ 0x01])
    parser = Parser(Sender.AUTOPILOT)
    parser.events_in_runs(bad + good)
    assert parser.stats.bytes_discarded == 25 and parser.stats.bytes_unframed == 0
    unframed_m = bytes(b for b in bad if b not in b"PR")  # no frame can start in it
    parser.events_in_runs(unframed_m + good)
    assert parser.stats.bytes_unframed == len(unframed_m)
