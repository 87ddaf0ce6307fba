"""The autopilot's sonar module (manual chapter 7), as a sans-IO state machine.

This module owns what a reader of a Ping1D does, as the manual's module
`sonar_bluerobotics` describes it: at start it asks for the protocol version,
the device id and the speed of sound, then starts the `distance_simple`
stream; it keeps the latest distance and confidence; at the end it stops the
stream. Added for a reader that runs for months: a reading older than
`max_age_s` is reported with confidence 0 (a silent sonar is not a bottom), and
a stream that stays silent for `restart_after_s` is started again (a Ping that
was power-cycled forgets it was streaming).

The request bytes are exactly the manual's tables 7.2-7.7 (the protocol
version request goes to device 0, the others to device 1), so this client
and the firmware put the same bytes on the wire.

It does no I/O and reads no clock: the caller passes `now` (seconds, any
monotonic origin) and writes the bytes it is given.
"""

from __future__ import annotations

from dataclasses import dataclass

from cc_daemon.core.cast.bottom import sounding_valid
from cc_daemon.drivers.sonar import ping
from cc_daemon.drivers.sonar.ping import (
    BadFrame,
    DeviceId,
    DistanceSimple,
    PingStream,
    ProtocolVersion,
    SpeedOfSound,
)


@dataclass(frozen=True, slots=True)
class SonarReading:
    """One echo: distance to the bottom and the sonar's confidence in it, at `at`."""

    distance_mm: int
    confidence_pct: int
    at: float  # the caller's clock, when the reading arrived

    @property
    def distance_m(self) -> float:
        return self.distance_mm / 1000.0

    @property
    def valid(self) -> bool:
        """False for a reading that cannot be true (confidence > 100, distance >= 1 km)."""
        return sounding_valid(self.distance_mm, self.confidence_pct)


NO_READING = SonarReading(0, 0, float("-inf"))


def start_requests() -> bytes:
    """The manual's start sequence, in its order: tables 7.2, 7.7, 7.6, then 7.4."""
    return (
        ping.request(ping.PROTOCOL_VERSION, dst=0)
        + ping.request(ping.DEVICE_ID)
        + ping.request(ping.SPEED_OF_SOUND)
        + ping.encode(ping.CONTINUOUS_START, dst=1, id=ping.DISTANCE_SIMPLE)
    )


def stop_request() -> bytes:
    """Table 7.5: stop the distance_simple stream."""
    return ping.encode(ping.CONTINUOUS_STOP, dst=1, id=ping.DISTANCE_SIMPLE)


class SonarClient:
    """See the module docstring. `now` must never go backwards."""

    def __init__(self, *, max_age_s: float = 1.0, restart_after_s: float = 3.0) -> None:
        if max_age_s <= 0:
            raise ValueError(f"max_age_s={max_age_s} is invalid: allowed > 0")
        if restart_after_s <= 0:
            raise ValueError(f"restart_after_s={restart_after_s} is invalid: allowed > 0")
        self.max_age_s = max_age_s
        self.restart_after_s = restart_after_s
        self._stream = PingStream()
        self.latest = NO_READING
        self.protocol_version: tuple[int, int, int] | None = None
        self.device_id: int | None = None
        self.speed_of_sound_mm_s: int | None = None
        self.readings = 0
        self.starts = 0
        self._started_at: float | None = None
        self._heard_at = float("-inf")  # the last distance_simple

    @property
    def bad_frames(self) -> int:
        return self._stream.errors

    def start(self, now: float) -> bytes:
        """The bytes to write when the port opens (or reopens)."""
        self._started_at = now
        self.starts += 1
        return start_requests()

    def stop(self) -> bytes:
        """The bytes to write before closing the port."""
        self._started_at = None
        return stop_request()

    def poll(self, now: float) -> bytes:
        """Bytes due at `now`: the start sequence again if the stream went silent."""
        started = self._started_at
        if started is None:
            return b""
        silent_since = max(started, self._heard_at)
        if now - silent_since >= self.restart_after_s:
            return self.start(now)
        return b""

    def feed(self, now: float, data: bytes) -> list[SonarReading]:
        """Take bytes from the sonar; the new readings they carried."""
        new: list[SonarReading] = []
        for envelope in self._stream.feed(data):
            event = envelope.event
            if isinstance(event, DistanceSimple):
                # As it arrived: an impossible value is flagged (`valid`), never mended.
                reading = SonarReading(event.distance_mm, event.confidence_pct, now)
                self.latest = reading
                self._heard_at = now
                self.readings += 1
                new.append(reading)
            elif isinstance(event, ProtocolVersion):
                self.protocol_version = (event.major, event.minor, event.patch)
            elif isinstance(event, DeviceId):
                self.device_id = event.device_id
            elif isinstance(event, SpeedOfSound):
                self.speed_of_sound_mm_s = event.mm_s
            elif isinstance(event, BadFrame):
                continue  # counted by the stream; the next reading is 250 ms away
        return new

    def reading(self, now: float) -> SonarReading:
        """The latest reading; with confidence 0 if it is older than `max_age_s`."""
        latest = self.latest
        if now - latest.at > self.max_age_s:
            return SonarReading(latest.distance_mm, 0, latest.at)
        return latest
