"""Timestamps for the frames the CC sends, in the autopilot's clock.

The value is the last timestamp received from the autopilot plus the whole
seconds since it arrived, modulo 65536; before any autopilot frame, the whole
seconds since the daemon started. Received timestamps are information only:
one that sticks at 0 or jumps is taken as it is, never used to reject or
reorder anything. Pure: `now` is passed in.
"""

from __future__ import annotations

import math

from cc_daemon.protocol.messages import TIMESTAMP_WIRE_MOD


class AutopilotTime:
    def __init__(self, started_at: float) -> None:
        self._base = 0
        self._base_at = started_at

    def observe(self, timestamp_s: int, now: float) -> None:
        """An autopilot frame carrying `timestamp_s` arrived at `now`."""
        self._base = timestamp_s
        self._base_at = now

    def at(self, now: float) -> int:
        elapsed = max(0, math.floor(now - self._base_at))
        return (self._base + elapsed) % TIMESTAMP_WIRE_MOD
