"""The messages of the autopilot <-> companion-computer link, as values.

This module owns the *meaning* of each frame: field names with their units,
the ranges the wire can carry, and convenience views in degrees and metres. It
knows nothing of bytes (that is `frames`) and does no I/O.

Messages are NamedTuples (measured: several times cheaper to build than a
frozen dataclass, which matters at hundreds of thousands of frames a second).
Equality includes the type, so `DepthReport(72, 0) != Finished(72, 0)` even
though both are the tuple `(72, 0)`.

Construction validates every field and raises `FieldError` (a `ValueError`)
naming it. Two fields are deliberately open-ended because the wire rules say
what happens to out-of-range values: `timestamp_s` is taken modulo 65536 and
`depth_mm` saturates at 65535 when encoded.
"""

from typing import Any, ClassVar, NamedTuple

from cc_daemon.core.errors import FieldError

LON_E7_MAX = 1_800_000_000  # 180 degrees
LAT_E7_MAX = 900_000_000  # 90 degrees
ALT_MM_MAX = 0xFFFFFF  # sign byte + 3-byte magnitude, as the firmware encodes it
SONAR_MM_MAX = 0xFFFFFFFF
CONFIDENCE_MAX = 100
DEPTH_MM_WIRE_MAX = 0xFFFF
TIMESTAMP_WIRE_MOD = 0x10000
MODE_MAX = 0xFF


def _check_int(field: str, value: object, low: int, high: int | None) -> None:
    if type(value) is not int:  # bool is an int subclass and is not a number here
        raise FieldError(field, value, "an int")
    if value < low or (high is not None and value > high):
        allowed = f"{low}..{high}" if high is not None else f">= {low}"
        raise FieldError(field, value, allowed)


class _Typed:
    """Mixin: type-aware equality and hashing for NamedTuple messages."""

    __slots__ = ()

    def __eq__(self, other: object) -> bool:
        # super() is the NamedTuple's tuple in every concrete message's MRO.
        return type(self) is type(other) and super().__eq__(other)

    def __ne__(self, other: object) -> bool:
        return not self.__eq__(other)

    def __hash__(self) -> int:
        return hash((type(self).__name__, tuple.__hash__(self)))  # type: ignore[arg-type]


class _PositionFields(NamedTuple):
    timestamp_s: int
    lon_e7: int
    lat_e7: int
    alt_mm: int
    sonar_distance_mm: int
    sonar_confidence_pct: int


def _check_position(
    timestamp_s: int,
    lon_e7: int,
    lat_e7: int,
    alt_mm: int,
    sonar_distance_mm: int,
    sonar_confidence_pct: int,
) -> None:
    _check_int("timestamp_s", timestamp_s, 0, None)
    _check_int("lon_e7", lon_e7, -LON_E7_MAX, LON_E7_MAX)
    _check_int("lat_e7", lat_e7, -LAT_E7_MAX, LAT_E7_MAX)
    _check_int("alt_mm", alt_mm, -ALT_MM_MAX, ALT_MM_MAX)
    _check_int("sonar_distance_mm", sonar_distance_mm, 0, SONAR_MM_MAX)
    _check_int("sonar_confidence_pct", sonar_confidence_pct, 0, CONFIDENCE_MAX)


class _PositionViews:
    """Views in degrees and metres, shared by `P-T` and `P-M`."""

    __slots__ = ()
    lon_e7: int
    lat_e7: int
    alt_mm: int
    sonar_distance_mm: int

    @property
    def lon_deg(self) -> float:
        return self.lon_e7 / 1e7

    @property
    def lat_deg(self) -> float:
        return self.lat_e7 / 1e7

    @property
    def alt_m(self) -> float:
        return self.alt_mm / 1000.0

    @property
    def sonar_distance_m(self) -> float:
        return self.sonar_distance_mm / 1000.0


class Telemetry(_Typed, _PositionViews, _PositionFields):
    """`P-T`: the autopilot's periodic fix and sonar reading."""

    __slots__ = ()
    frame: ClassVar[str] = "P-T"

    def __new__(
        cls,
        timestamp_s: int,
        lon_e7: int,
        lat_e7: int,
        alt_mm: int,
        sonar_distance_mm: int,
        sonar_confidence_pct: int,
    ) -> Any:
        fields = (timestamp_s, lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct)
        _check_position(*fields)
        return tuple.__new__(cls, fields)


class _StartFields(NamedTuple):
    timestamp_s: int
    lon_e7: int
    lat_e7: int
    alt_mm: int
    sonar_distance_mm: int
    sonar_confidence_pct: int
    mode: int | None = None


class StartMeasuring(_Typed, _PositionViews, _StartFields):
    """`P-M` (or `P-G` on one firmware revision): lower the probe here.

    `mode` is the measuring-mode byte of the firmware's 26-byte `M` (offset 23),
    or None for the manual's 25-byte frame. Its meaning is undocumented (every
    2023 firmware revision sends 0): it is recorded, never acted on.
    """

    __slots__ = ()
    frame: ClassVar[str] = "P-M"

    def __new__(
        cls,
        timestamp_s: int,
        lon_e7: int,
        lat_e7: int,
        alt_mm: int,
        sonar_distance_mm: int,
        sonar_confidence_pct: int,
        mode: int | None = None,
    ) -> Any:
        fields = (timestamp_s, lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct)
        _check_position(*fields)
        if mode is not None:
            _check_int("mode", mode, 0, MODE_MAX)
        return tuple.__new__(cls, (*fields, mode))


class _TimestampFields(NamedTuple):
    timestamp_s: int


class _TimestampMessage(_Typed, _TimestampFields):
    __slots__ = ()
    frame: ClassVar[str]

    def __new__(cls, timestamp_s: int) -> Any:
        _check_int("timestamp_s", timestamp_s, 0, None)
        return tuple.__new__(cls, (timestamp_s,))


class ProbePositionRequest(_TimestampMessage):
    """`P-S`: where is the probe?"""

    __slots__ = ()
    frame = "P-S"


class ProbeUp(_TimestampMessage):
    """`P-U`: the safety pilot holds the RC probe stick up (firmware 7ab06076 on).

    Sent about once a second while the stick is held; no reply is expected.
    """

    __slots__ = ()
    frame = "P-U"


class ProbeDown(_TimestampMessage):
    """`P-D`: the safety pilot holds the RC probe stick down. No reply is expected."""

    __slots__ = ()
    frame = "P-D"


class Ack(_TimestampMessage):
    """`R-O`: measurement request acknowledged."""

    __slots__ = ()
    frame = "R-O"


class _DepthFields(NamedTuple):
    timestamp_s: int
    depth_mm: int


class _DepthMessage(_Typed, _DepthFields):
    __slots__ = ()
    frame: ClassVar[str]

    def __new__(cls, timestamp_s: int, depth_mm: int) -> Any:
        _check_int("timestamp_s", timestamp_s, 0, None)
        _check_int("depth_mm", depth_mm, 0, None)
        return tuple.__new__(cls, (timestamp_s, depth_mm))

    @property
    def depth_m(self) -> float:
        return self.depth_mm / 1000.0


class DepthReport(_DepthMessage):
    """`R-M`: the probe depth, every second while measuring."""

    __slots__ = ()
    frame = "R-M"


class Finished(_DepthMessage):
    """`R-F`: the measurement is over and the probe is home."""

    __slots__ = ()
    frame = "R-F"


class ProbePosition(_DepthMessage):
    """`R-P`: the answer to `P-S`."""

    __slots__ = ()
    frame = "R-P"


class FaultReport(_DepthMessage):
    """`R-L`: the probe may be down and cannot come home; sent in place of `R-M`.

    The 2023 firmware's `R` parser stores the type byte (76) as its receive
    error, which its SERIAL_COM telemetry carries to the ground station, and
    goes on waiting at the station (it is not `R-F`). It does not read the
    depth; we carry the best estimate there for `decode` and the logs.
    """

    __slots__ = ()
    frame = "R-L"


AutopilotMessage = Telemetry | StartMeasuring | ProbePositionRequest | ProbeUp | ProbeDown
CcMessage = Ack | DepthReport | Finished | ProbePosition | FaultReport
Message = AutopilotMessage | CcMessage

MESSAGE_TYPES: tuple[type[Message], ...] = (
    Telemetry,
    StartMeasuring,
    ProbePositionRequest,
    ProbeUp,
    ProbeDown,
    Ack,
    DepthReport,
    Finished,
    ProbePosition,
    FaultReport,
)


def as_dict(message: Message) -> dict[str, Any]:
    """The message as `{"frame": "P-T", field: value, ...}` (for JSON output).

    A 25-byte `P-M` has no mode byte, so it has no `mode` key either.
    """
    fields = message._asdict()
    if fields.get("mode", 0) is None:
        del fields["mode"]
    return {"frame": message.frame, **fields}
