"""Injected line noise: bit flips on the bytes crossing the simulated cable.

This module owns `BitFlipper`, a byte filter for `FramePort` that flips one
random bit in a byte with a given probability, counts what it did and notes
when it did it. It is seeded, so a noisy run is reproducible. It never drops,
adds or reorders bytes (a real UART's noise flips bits; losing bytes is the
cable's business).

At most one bit is flipped in any `span` consecutive bytes (by default the
longest frame, 26 bytes: the firmware's `M`), so no frame ever carries more than one flipped bit.
The protocol's checksum is a plain sum of the bytes: one flipped bit always
changes it, two can cancel out. The simulated line is therefore one whose
checksum catches every error, and a frame that passes its checksum is a frame
the peer really sent: whatever it says is the sender's responsibility.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable

from cc_daemon.core.protocol.frames import MAX_FRAME_LENGTH


class BitFlipper:
    """`flipper(data)` returns `data` with some bits flipped; see the module docstring.

    `flip_times` holds the `clock()` time of every flipped bit, in order: the
    simulated autopilot excuses a lost answer only when a flip happened near it.
    """

    def __init__(
        self,
        rate: float,
        seed: int,
        *,
        span: int = MAX_FRAME_LENGTH,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"rate={rate} is invalid: allowed 0..1 (a probability per byte)")
        if span < 1:
            raise ValueError(f"span={span} is invalid: allowed >= 1 (bytes)")
        self.rate = rate
        self.span = span
        self._clock = clock
        self._rng = random.Random(seed)
        self._quiet = 0  # bytes still to pass untouched after the last flip
        self.bytes_seen = 0
        self.bits_flipped = 0
        self.flip_times: list[float] = []

    def __call__(self, data: bytes) -> bytes:
        self.bytes_seen += len(data)
        if self.rate == 0.0:
            return data
        out = bytearray(data)
        rng = self._rng
        flipped = 0
        for i in range(len(out)):
            if self._quiet:
                self._quiet -= 1
                continue
            if rng.random() < self.rate:
                out[i] ^= 1 << rng.randrange(8)
                flipped += 1
                self._quiet = self.span - 1
        if flipped:
            now = self._clock()
            self.bits_flipped += flipped
            self.flip_times.extend([now] * flipped)
        return bytes(out)
