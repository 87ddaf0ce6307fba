"""The autopilot <-> companion-computer wire protocol, sans-IO.

Import from here: messages (`Telemetry`, `StartMeasuring`, ...), `encode`, and
the streaming `Parser`. Nothing in this package does I/O, sleeps or reads a
clock.
"""

from cc_daemon.core.protocol.frames import AutopilotType, CcType, Sync, checksum, encode
from cc_daemon.core.protocol.messages import (
    MESSAGE_TYPES,
    Ack,
    AutopilotMessage,
    CcMessage,
    DepthReport,
    FaultReport,
    Finished,
    Message,
    ProbeDown,
    ProbePosition,
    ProbePositionRequest,
    ProbeUp,
    StartMeasuring,
    Telemetry,
    as_dict,
)
from cc_daemon.core.protocol.parser import CorruptFrame, ErrorKind, Parser, ParserStats, Sender
from cc_daemon.core.protocol.runs import TelemetryRun

__all__ = [
    "MESSAGE_TYPES",
    "Ack",
    "AutopilotMessage",
    "AutopilotType",
    "CcMessage",
    "CcType",
    "CorruptFrame",
    "DepthReport",
    "ErrorKind",
    "FaultReport",
    "Finished",
    "Message",
    "Parser",
    "ParserStats",
    "ProbeDown",
    "ProbePosition",
    "ProbePositionRequest",
    "ProbeUp",
    "Sender",
    "StartMeasuring",
    "Sync",
    "Telemetry",
    "TelemetryRun",
    "as_dict",
    "checksum",
    "encode",
]
