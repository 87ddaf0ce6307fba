"""Injected line noise: seeded bit flips, counted, never a lost byte."""

from __future__ import annotations

import pytest

from cc_daemon.sim.noise import BitFlipper


def test_flips_single_bits_at_about_the_given_rate_and_counts_them() -> None:
    flipper = BitFlipper(0.1, seed=3)
    data = bytes(range(256)) * 40
    out = flipper(data)
    assert len(out) == len(data)
    flipped = [bin(a ^ b).count("1") for a, b in zip(data, out, strict=True)]
    assert set(flipped) <= {0, 1}  # one bit per mangled byte
    assert sum(flipped) == flipper.bits_flipped
    assert 0.08 * len(data) < flipper.bits_flipped < 0.12 * len(data)
    assert flipper.bytes_seen == len(data)


def test_same_seed_same_noise_and_zero_rate_is_a_clean_line() -> None:
    data = b"PT" * 500
    assert BitFlipper(0.05, 9)(data) == BitFlipper(0.05, 9)(data)
    clean = BitFlipper(0.0, 1)
    assert clean(data) == data
    assert clean.bits_flipped == 0


@pytest.mark.parametrize("rate", [-0.1, 1.5])
def test_a_rate_outside_zero_to_one_is_refused(rate: float) -> None:
    with pytest.raises(ValueError, match="probability per byte"):
        BitFlipper(rate, 1)
