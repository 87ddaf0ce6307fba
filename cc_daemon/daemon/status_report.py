"""The status document: what the running daemon says about itself.

A JSON-able dict assembled from `StatusInputs` (plain values the daemon hands
over: its snapshot, its port, the journal's health), one section per entry of
`SECTIONS`; it never sees the `Daemon` itself. To add a section (jog state,
sonde, ...), write a function `(Source) -> JSON-able` and add one line to
`SECTIONS`; the
server, `cc-daemon status --json` and the tests take it as it comes, and the
human view shows sections it does not know as `name: value`.

It only reads: it never commands the winch, writes the journal or blocks (the
one system call it makes, statvfs for the journal's free space, is cheap and
the server caches the document).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cc_daemon import __version__
from cc_daemon.core.cast.timestamps import swap_bytes
from cc_daemon.core.protocol import as_dict
from cc_daemon.core.status import DaemonStatus
from cc_daemon.core.winch.status import WinchStatus
from cc_daemon.ground.clocksync import ClockSync, clock_sync
from cc_daemon.store import JournalHealth


@dataclass(frozen=True, slots=True)
class StatusInputs:
    """What the daemon hands the status document, taken at one instant."""

    snapshot: DaemonStatus
    port: str
    baudrate: int
    winch_backend: str
    journal_health: Callable[[], JournalHealth] | None
    monotonic: float  # the daemon's clock, for ages
    wall: float
    uptime_s: float
    simulated: bool = False  # no real motor moves (a simulated winch, or mock pins)


@dataclass(frozen=True, slots=True)
class Source:
    """Everything a section may read, taken at one instant."""

    inputs: StatusInputs
    clock: ClockSync

    @property
    def snapshot(self) -> DaemonStatus:
        return self.inputs.snapshot

    @property
    def monotonic(self) -> float:
        return self.inputs.monotonic

    @property
    def wall(self) -> float:
        return self.inputs.wall

    @property
    def uptime_s(self) -> float:
        return self.inputs.uptime_s


def _daemon(src: Source) -> dict[str, Any]:
    return {
        "state": "stopping" if src.snapshot.stopping else "serving",
        "version": __version__,
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "uptime_s": round(src.uptime_s, 1),
        "wall_time": round(src.wall, 3),
        "simulated": src.inputs.simulated,
    }


def _link(src: Source) -> dict[str, Any]:
    return {
        "up": src.snapshot.link_up,
        "port": src.inputs.port,
        "baudrate": src.inputs.baudrate,
        "port_losses": src.snapshot.port_losses,
        # Failed attempts to open it since it was last open (a missing USB adapter).
        "open_attempts": src.snapshot.port_open_attempts,
    }


def _fix(src: Source) -> dict[str, Any] | None:
    fix = src.snapshot.last_fix
    if fix is None:
        return None
    fields = as_dict(fix.message)
    # The autopilot's time in its real value: its two bytes read in the order the
    # session settled on (the deployed firmware writes them little-endian), as the
    # journal stores it, never the raw big-endian reading.
    order = src.snapshot.timestamp_order
    if order == "little":
        fields["timestamp_s"] = swap_bytes(fields["timestamp_s"])
    return {
        **fields,
        "timestamp_order": order,
        "timestamp_order_settled": src.snapshot.timestamp_order_settled,
        "age_s": round(src.monotonic - fix.monotonic, 1),
    }


def _range(w: WinchStatus | None) -> dict[str, float | None]:
    """Where the probe may be when its depth is an estimate (None: measured)."""
    if w is None or w.depth_low_m is None or w.depth_high_m is None:
        return {"depth_low_m": None, "depth_high_m": None}
    return {"depth_low_m": round(w.depth_low_m, 3), "depth_high_m": round(w.depth_high_m, 3)}


def _cast(src: Source) -> dict[str, Any]:
    s = src.snapshot
    return {
        "phase": s.phase,
        "cast_id": s.cast_id,
        "planned_depth_m": s.planned_depth_m,
        "depth_m": round(s.probe_depth_m, 3),
        # The probe may be down and cannot come home: R-L goes to the autopilot.
        "fault_reported": (
            {
                "depth_m": round(s.probe_depth_m, 3),
                "fault": s.winch_fault,
                "r_l_sent": s.fault_reports,
                **_range(s.winch),
            }
            if s.phase == "stranded"
            else None
        ),
    }


def _winch(src: Source) -> dict[str, Any]:
    w = src.snapshot.winch
    return {
        "backend": src.inputs.winch_backend,
        "depth_m": round(w.depth_m, 3) if w else None,
        "moving": w.moving if w else None,
        "at_home": w.at_home if w else None,
        "fault": (w.fault if w else None) or src.snapshot.winch_fault,
        "sensor_fault": w.sensor_fault if w else None,
        **_range(w),
    }


def _journal(src: Source) -> dict[str, Any] | None:
    if src.inputs.journal_health is None:
        return None
    health = src.inputs.journal_health()
    try:
        stats = os.statvfs(health.path.parent)
        free: int | None = stats.f_bavail * stats.f_frsize
    except OSError:
        free = None
    return {
        "path": str(health.path),
        "writable": health.writable,
        "pending_rows": health.pending_rows,
        "rows_written": health.rows_written,
        "write_errors": health.write_errors,
        "dropped_rows": health.dropped_rows,
        "last_error": health.last_error,
        "writer_alive": health.writer_alive,
        "spilled_rows": health.spilled_rows,  # of pending_rows, waiting in spill files
        "spill_files": [str(p) for p in health.spill_files],
        "disk_free_bytes": free,
    }


def _counters(src: Source) -> dict[str, int]:
    s = src.snapshot
    return {
        "frames_in": s.frames_in,
        "frames_out": s.frames_out,
        "corrupt_frames": s.corrupt_frames,
        "casts_completed": s.casts_completed,
        "casts_aborted": s.casts_aborted,
        "casts_skipped": s.casts_skipped,
        "port_losses": s.port_losses,
    }


SECTIONS: list[tuple[str, Callable[[Source], Any]]] = [
    ("daemon", _daemon),
    ("link", _link),
    ("fix", _fix),
    ("cast", _cast),
    ("winch", _winch),
    ("journal", _journal),
    ("counters", _counters),
    ("clock", lambda src: src.clock.as_dict()),
]


def status_document(inputs: StatusInputs) -> dict[str, Any]:
    """Every section; one that fails says so in its place instead of sinking the rest."""
    src = Source(inputs, clock_sync())
    out: dict[str, Any] = {}
    for name, section in SECTIONS:
        try:
            out[name] = section(src)
        except Exception as exc:
            out[name] = {"error": f"{type(exc).__name__}: {exc}"}
    return out
