"""Injected line noise: seeded bit flips, counted and timed, never a lost byte."""

from __future__ import annotations

import itertools
import random
from collections.abc import Callable

import pytest

from cc_daemon.core.protocol import (
    CorruptFrame,
    DepthReport,
    Finished,
    Message,
    Parser,
    Sender,
    StartMeasuring,
    encode,
)
from cc_daemon.sim.noise import BitFlipper


def test_flips_single_bits_never_two_within_a_frame_length_and_counts_them() -> None:
    flipper = BitFlipper(0.1, seed=3)
    data = bytes(range(256)) * 40
    out = flipper(data)
    assert len(out) == len(data)
    flipped = [bin(a ^ b).count("1") for a, b in zip(data, out, strict=True)]
    assert set(flipped) <= {0, 1}  # one bit per mangled byte
    assert sum(flipped) == flipper.bits_flipped
    where = [i for i, n in enumerate(flipped) if n]
    assert min(b - a for a, b in itertools.pairwise(where)) >= 25  # the longest frame
    # A flip per byte with probability p, then 24 bytes left alone: p / (1 + 24 p).
    expected = 0.1 / (1 + 24 * 0.1) * len(data)
    assert 0.8 * expected < flipper.bits_flipped < 1.2 * expected
    assert flipper.bytes_seen == len(data)


def test_the_quiet_span_carries_across_calls() -> None:
    flipper = BitFlipper(1.0, seed=1, span=8)
    out = b"".join(flipper(bytes(3)) for _ in range(8))  # 24 bytes, three at a time
    assert [i for i, byte in enumerate(out) if byte] == [0, 8, 16]


def test_every_flip_is_timed() -> None:
    ticks = iter(range(100))
    flipper = BitFlipper(1.0, seed=1, span=4, clock=lambda: float(next(ticks)))
    chunks = [flipper(bytes(n)) for n in (8, 3, 3, 1)]
    assert [[i for i, b in enumerate(c) if b] for c in chunks] == [[0, 4], [0], [1], []]
    assert flipper.flip_times == [0.0, 0.0, 1.0, 2.0]  # the clock is read once per call that flips
    assert flipper.bits_flipped == 4


def test_same_seed_same_noise_and_zero_rate_is_a_clean_line() -> None:
    data = b"PT" * 500
    assert BitFlipper(0.05, 9)(data) == BitFlipper(0.05, 9)(data)
    clean = BitFlipper(0.0, 1)
    assert clean(data) == data
    assert clean.bits_flipped == 0
    assert clean.flip_times == []


@pytest.mark.parametrize(
    ("listen", "make"),
    [
        (
            Sender.AUTOPILOT,
            lambda r: StartMeasuring(
                r.randrange(100), -37260579, 404506308, 702385, r.randrange(500, 6000), 95
            ),
        ),
        (Sender.CC, lambda r: DepthReport(r.randrange(100), r.randrange(0, 5000))),
        (Sender.CC, lambda r: Finished(r.randrange(100), 0)),
    ],
)
def test_no_mangled_frame_passes_the_checksum(
    listen: Sender, make: Callable[[random.Random], Message]
) -> None:
    """At most one flipped bit per frame: the plain-sum checksum catches every one.

    (With two flips per frame allowed, about 1 in 400 noisy P-M frames got
    through at --corrupt 0.02: the sum can't see +2^k and -2^k.)
    """
    rng = random.Random(0)
    flipper = BitFlipper(0.2, seed=5)
    parser = Parser(listen)
    sent = [make(rng) for _ in range(5000)]
    heard = [e for f in sent for e in parser.events(flipper(encode(f)))]
    heard += parser.close()
    good = [e for e in heard if not isinstance(e, CorruptFrame)]
    assert flipper.bits_flipped > 500
    assert len(good) < len(sent)
    remaining = iter(sent)
    assert all(frame in remaining for frame in good)  # what was sent, in order, or nothing


@pytest.mark.parametrize("rate", [-0.1, 1.5])
def test_a_rate_outside_zero_to_one_is_refused(rate: float) -> None:
    with pytest.raises(ValueError, match="probability per byte"):
        BitFlipper(rate, 1)


def test_a_span_under_one_byte_is_refused() -> None:
    with pytest.raises(ValueError, match="span"):
        BitFlipper(0.1, 1, span=0)
