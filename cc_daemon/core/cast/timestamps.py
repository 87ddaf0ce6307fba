"""The autopilot's clock: its timestamps' byte order, and timestamps for our frames.

`TimestampOrder` decides how to read the two timestamp bytes of the
autopilot's frames. The manual says big-endian; the deployed 2023 firmware
writes them little-endian (low byte first) with a routine of its own. With
the setting "auto" it watches consecutive `T` frames about a second apart:
a counter that steps by 1 in one order steps by 256 (or 257) in the other.
Until it has decided it reads big-endian, as the manual says.

`AutopilotTime` stamps the frames the CC sends: the last timestamp received
from the autopilot (in its real value) plus the whole seconds since it
arrived, modulo 65536; before any autopilot frame, the whole seconds since
the daemon started. Our own frames stay big-endian: the firmware reads them so.

Received timestamps are information only: one that sticks at 0 or jumps is
taken as it is, never used to reject or reorder anything. Pure: `now` is
passed in; nothing here logs, sleeps or reads a clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from cc_daemon.core.protocol.messages import TIMESTAMP_WIRE_MOD

Order = Literal["big", "little"]
Setting = Literal["auto", "big", "little"]

VOTES_NEEDED = 3  # agreeing pairs of T frames (with none against) to decide
PAIR_MIN_S = 0.5  # T frames closer or further apart than these say nothing
PAIR_MAX_S = 3.0


def swap_bytes(raw: int) -> int:
    """The two bytes read big-endian as `raw`, read little-endian instead."""
    return (raw & 0xFF) << 8 | raw >> 8


@dataclass(frozen=True, slots=True)
class OrderDecision:
    """What "auto" concluded, with the evidence: the (timestamp read big-endian,
    seconds since the previous `T`) pairs that voted."""

    order: Order
    votes: int
    against: int
    evidence: tuple[tuple[int, int, float], ...]  # (previous raw, raw, seconds apart)


class TimestampOrder:
    def __init__(self, setting: Setting = "auto") -> None:
        self.setting = setting
        self.order: Order = "big" if setting == "auto" else setting
        self.decided = setting != "auto"
        self._last: tuple[int, float] | None = None
        self._votes: dict[Order, list[tuple[int, int, float]]] = {"big": [], "little": []}

    def decode(self, raw: int) -> int:
        """The autopilot's time, from the two bytes the parser read big-endian."""
        return swap_bytes(raw) if self.order == "little" else raw

    def observe_telemetry(self, raw: int, now: float) -> OrderDecision | None:
        """A `T` frame whose timestamp read big-endian is `raw` arrived at `now`.

        Returns the decision the one time "auto" makes it, else None.
        """
        if self.decided:
            return None
        last, self._last = self._last, (raw, now)
        if last is None:
            return None
        last_raw, last_at = last
        apart = now - last_at
        if not PAIR_MIN_S <= apart <= PAIR_MAX_S:
            return None
        # Elapsed whole seconds on a 1 s clock sampled `apart` seconds apart.
        plausible = range(max(1, math.floor(apart)), math.ceil(apart) + 2)
        big = (raw - last_raw) % TIMESTAMP_WIRE_MOD in plausible
        little = (swap_bytes(raw) - swap_bytes(last_raw)) % TIMESTAMP_WIRE_MOD in plausible
        if big == little:
            return None  # stuck (0, 0, ...), a jump, or a wrap both orders read alike
        voted: Order = "big" if big else "little"
        self._votes[voted].append((last_raw, raw, round(apart, 3)))
        other: Order = "little" if voted == "big" else "big"
        if len(self._votes[voted]) - len(self._votes[other]) < VOTES_NEEDED:
            return None
        self.order = voted
        self.decided = True
        return OrderDecision(
            voted,
            len(self._votes[voted]),
            len(self._votes[other]),
            tuple(self._votes[voted][-VOTES_NEEDED:]),
        )


class AutopilotTime:
    def __init__(self, started_at: float) -> None:
        self._base = 0
        self._base_at = started_at

    def observe(self, timestamp_s: int, now: float) -> None:
        """An autopilot frame carrying `timestamp_s` (its real value) arrived at `now`."""
        self._base = timestamp_s
        self._base_at = now

    def at(self, now: float) -> int:
        elapsed = max(0, math.floor(now - self._base_at))
        return (self._base + elapsed) % TIMESTAMP_WIRE_MOD
