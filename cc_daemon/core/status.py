"""What the running daemon says about itself, as plain data.

`DaemonStatus` is one instant of the daemon's state (the link, the cast, the
winch, the counters) and `Fix` the latest position report. They are values:
the daemon fills them in, and the status document, the simulator's view and
the sonde's duty read them, without ever holding the daemon itself.
"""

from __future__ import annotations

from dataclasses import dataclass

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.core.winch.status import WinchStatus


@dataclass(frozen=True, slots=True)
class Fix:
    """The latest position report, with when it arrived."""

    message: Telemetry | StartMeasuring
    monotonic: float
    wall: float


@dataclass(frozen=True, slots=True)
class DaemonStatus:
    link_up: bool
    phase: str  # "idle" or the running cast's phase
    probe_depth_m: float
    planned_depth_m: float | None
    cast_id: int | None
    frames_in: int
    frames_out: int
    corrupt_frames: int
    casts_completed: int
    casts_aborted: int
    casts_skipped: int
    winch_fault: str | None
    port_losses: int
    last_fix: Fix | None
    winch: WinchStatus | None = None
    stopping: bool = False
    jog: str | None = None  # "up" / "down" while the RC stick jogs the probe
    lost_start: str | None = None  # set while the autopilot may wait on an unread M
    port_open_attempts: int = 0  # failed attempts to open the port since it was last open
    fault_reports: int = 0  # R-L sent for the running cast (stranded, refused)
    # How the autopilot's two timestamp bytes are read (`cast.timestamps`): the
    # order assumed until "auto" decides, then the one it settled on.
    timestamp_order: str = "big"
    timestamp_order_settled: bool = False
