"""A station with no trusted sonar bottom, through the daemon in process: a real pty
as the autopilot's line, a real journal file, the simulated winch recording what it
is told (issue 19, "Bottom without a trusted sounding")."""

from __future__ import annotations

import asyncio
import json
import sqlite3
from pathlib import Path
from typing import Any

import structlog

from cc_daemon.core.protocol import Finished
from cc_daemon.core.winch.physics import LinePhysics
from cc_daemon.core.winch.status import ApproachSpeed
from cc_daemon.daemon.service import EXIT_OK, Daemon
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import station
from tests.test_service import RecordingWinch, _settings


class OneSpeedWinch:
    """A winch with one speed (no `move_slowly_to`): the recording winch's physics
    behind the bare Winch interface."""

    def __init__(self) -> None:
        self._inner = RecordingWinch()
        self.calls = self._inner.calls
        self.status = self._inner.status
        self.move_to = self._inner.move_to
        self.stop = self._inner.stop
        self.wait_change = self._inner.wait_change
        self.close = self._inner.close


async def _cast(tmp_path: Path, winch: Any, sonar_mm: int, confidence: int) -> None:
    with PtyPair(tmp_path / "tty") as pty:
        daemon = Daemon(_settings(tmp_path, pty.path), winch=winch)
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), 5)
        await port.send(station(sonar_mm=sonar_mm, confidence=confidence))
        finished = None
        while (got := await port.receive(5)) is not None:
            if isinstance(got.message, Finished):
                finished = got.message
                break
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, 5) == EXIT_OK
        await port.close()
    assert finished is not None and finished.depth_mm == 0


def _journal(tmp_path: Path) -> tuple[list[tuple[Any, ...]], dict[str, Any]]:
    with sqlite3.connect(tmp_path / "j.db") as db:
        casts = db.execute("SELECT planned_depth_m, outcome, plan_json FROM casts").fetchall()
        events = {
            kind: json.loads(detail)
            for kind, detail in db.execute("SELECT kind, detail_json FROM events")
        }
    return casts, events


async def test_a_sentinel_bottom_casts_blind_slowly_and_is_journaled_so(tmp_path: Path) -> None:
    winch = RecordingWinch()
    assert isinstance(winch, ApproachSpeed)  # the simulated winch has an approach speed
    # FAST_CAST's target is 3 m; 4294967295 mm is no bottom at all.
    await _cast(tmp_path, winch, sonar_mm=4294967295, confidence=100)
    moves = [c for c in winch.calls if c != "stop"]
    assert moves[0] == "slowly 1.0"  # the default blind cap, at the approach speed
    assert "move_to 0.0" in moves  # home at the usual speed
    assert not any(c.startswith("move_to 3") for c in moves)
    [(planned, outcome, plan_json)] = _journal(tmp_path)[0]
    assert (planned, outcome) == (1.0, "completed")
    plan = json.loads(plan_json)
    why = "sonar distance 4294967295 mm cannot be a bottom"
    assert (plan["blind"], plan["limited_by"]) == (why, "blind")
    assert _journal(tmp_path)[1]["cast_blind"] == {"cast_id": 1, "reason": why, "depth_m": 1.0}


async def test_a_winch_without_an_approach_speed_says_so_once(tmp_path: Path) -> None:
    winch = OneSpeedWinch()
    assert not isinstance(winch, ApproachSpeed)
    with structlog.testing.capture_logs() as logs:
        await _cast(tmp_path, winch, sonar_mm=2000, confidence=10)
    assert next(c for c in winch.calls if c != "stop") == "move_to 1.0"
    said = [e for e in logs if str(e["event"]).startswith("blind cast: this winch has no")]
    assert len(said) == 1 and said[0]["backend"] == "sim"
    blind = [e for e in logs if e["event"] == "no trusted sonar bottom: casting blind"]
    assert blind[0]["reason"] == "sonar confidence 10 % is under cast.min_sonar_confidence 70 %"


def test_the_simulated_line_runs_a_slow_motion_at_the_approach_speed() -> None:
    physics = LinePhysics(speed_m_s=0.5, max_line_m=20.0)
    physics.command(0.0, 1.0, slow=True)
    assert physics.arrival_time(0.0) == 4.0  # 1 m at half of 0.5 m/s
    assert physics.depth(2.0) == 0.5
    physics.command(4.0, 0.0)  # home at the line speed
    assert physics.arrival_time(4.0) == 6.0
