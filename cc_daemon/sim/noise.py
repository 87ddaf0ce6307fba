"""Injected line noise: bit flips on the bytes crossing the simulated cable.

This module owns `BitFlipper`, a byte filter for `FramePort` that flips one
random bit in each byte with a given probability and counts what it did. It is
seeded, so a noisy run is reproducible. It never drops, adds or reorders
bytes (a real UART's noise flips bits; losing bytes is the cable's business).
"""

from __future__ import annotations

import random


class BitFlipper:
    def __init__(self, rate: float, seed: int) -> None:
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"rate={rate} is invalid: allowed 0..1 (a probability per byte)")
        self.rate = rate
        self._rng = random.Random(seed)
        self.bytes_seen = 0
        self.bits_flipped = 0

    def __call__(self, data: bytes) -> bytes:
        self.bytes_seen += len(data)
        if self.rate == 0.0:
            return data
        out = bytearray(data)
        rng = self._rng
        for i in range(len(out)):
            if rng.random() < self.rate:
                out[i] ^= 1 << rng.randrange(8)
                self.bits_flipped += 1
        return bytes(out)
