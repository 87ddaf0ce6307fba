"""The two witnesses through the daemon, with the autopilot on a pty: no R-F with the
probe down when one sensor lies, and R-F (depth 0) once an operator's haul with the
RC stick brings both witnesses into agreement."""

from __future__ import annotations

import asyncio
import sqlite3
import time
from pathlib import Path

from cc_daemon.core.protocol import Ack, DepthReport, FaultReport, Finished, ProbeUp
from cc_daemon.daemon.service import EXIT_PROBE_MAY_BE_DOWN
from cc_daemon.sim.drum import DrumFaults
from cc_daemon.sim.port import Received
from tests.daemonkit import station
from tests.gpiokit import gpio_rig
from tests.test_gpio_daemon import Boat, _boat, _cast_rows


async def _until_stranded(boat: Boat, timeout: float = 60.0) -> list[Received]:
    frames: list[Received] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and boat.daemon.snapshot().phase != "stranded":
        got = await boat.port.receive(0.2)
        if got is not None:
            frames.append(got)
    return frames


async def test_a_switch_stuck_closed_strands_the_cast_until_the_stick_hauls_it_home(
    tmp_path: Path,
) -> None:
    faults = DrumFaults(switch_stuck_closed=True)
    async with gpio_rig(faults=faults) as rig, _boat(tmp_path, rig) as boat:
        await boat.port.send(station())
        frames = await _until_stranded(boat)
        assert boat.daemon.snapshot().phase == "stranded"
        fault = boat.daemon.snapshot().winch_fault or ""
        assert "never left the block" in fault
        assert rig.drum.line_m > 0.1 and rig.drum.motor() == (0, 0.0)
        assert not any(isinstance(f.message, Finished) for f in frames)
        more = [await boat.port.receive(1.2) for _ in range(2)]
        assert not any(r is not None and isinstance(r.message, Finished) for r in more)
        # The safety pilot holds the probe stick up: the haul home both witnesses verify.
        finished: Finished | None = None
        deadline = time.monotonic() + 60
        while finished is None and time.monotonic() < deadline:
            await boat.port.send(ProbeUp(7))
            got = await boat.port.receive(0.3)
            while got is not None and finished is None:
                if isinstance(got.message, Finished):
                    finished = got.message
                got = await boat.port.receive(0.05) if finished is None else None
        assert finished is not None and finished.depth_mm == 0
        assert rig.winch.status().at_home and rig.drum.line_m <= 0.15
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, 30) == 0
    [(outcome, reason, _backend, _sim)] = _cast_rows(tmp_path)
    assert outcome == "aborted" and "witnesses disagree" in reason


async def test_a_snag_mid_descent_never_gives_rf_and_exit_says_probe_down(
    tmp_path: Path,
) -> None:
    async with gpio_rig(faults=DrumFaults(snag_at_m=1.0)) as rig, _boat(tmp_path, rig) as boat:
        await boat.port.send(station())
        frames = await _until_stranded(boat)
        assert boat.daemon.snapshot().phase == "stranded"
        assert not any(isinstance(f.message, Finished) for f in frames)
        assert rig.drum.line_m > 0.9
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, 30) == EXIT_PROBE_MAY_BE_DOWN


async def test_failed_start_up_homing_refuses_every_cast_and_reports_the_fault(
    tmp_path: Path,
) -> None:
    # The switch stuck open: start-up homing hauls until its deadline and fails. The
    # GPIO winch says "homing failed: ...", the words main's refuses_casts reads.
    faults = DrumFaults(switch_stuck_open=True)
    async with (
        gpio_rig(line_m=1.0, faults=faults, max_line_m=2.0, start_up=False) as rig,
        _boat(tmp_path, rig) as boat,
    ):
        assert not rig.winch.homed
        assert (rig.winch.status().fault or "").startswith("homing failed: ")
        moved_at_start = rig.drum.max_line_seen
        await boat.port.send(station())
        # The fault, to the autopilot: at once, then every period, and nothing else. The
        # frames are counted, not timed: a loaded machine may deliver them late.
        received = []
        deadline = time.monotonic() + 60  # only a hang reaches it
        while sum(isinstance(m, FaultReport) for m in received) < 3:
            left = deadline - time.monotonic()
            assert left > 0, received
            got = await boat.port.receive(left)
            if got is not None:
                received.append(got.message)
        assert isinstance(received[0], Ack)
        assert not any(isinstance(m, Finished) for m in received)
        assert not any(isinstance(m, DepthReport) for m in received)
        assert rig.drum.motor() == (0, 0.0)
        assert rig.drum.max_line_seen == moved_at_start  # never paid out an inch
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, 30) == EXIT_PROBE_MAY_BE_DOWN
    with sqlite3.connect(tmp_path / "j.db") as db:
        [(detail,)] = db.execute(
            "SELECT detail_json FROM events WHERE kind = 'cast_refused'"
        ).fetchall()
    assert "homing failed: " in detail


async def test_winch_home_beside_the_daemon_hauls_in_past_the_witnesses_fault(
    tmp_path: Path,
) -> None:
    # `cc-daemon winch home` with the daemon running asks it to haul a stranded probe
    # in: on the GPIO winch that is an operator's haul, taken while the witnesses
    # disagree (a move_to would be refused), and it ends the station with R-F.
    async with (
        gpio_rig(faults=DrumFaults(switch_stuck_closed=True)) as rig,
        _boat(tmp_path, rig) as boat,
    ):
        await boat.port.send(station())
        await _until_stranded(boat)
        assert "witnesses disagree" in (rig.winch.status().fault or "")
        ok, message = boat.daemon.haul_home("test", "operator request")
        assert ok, message
        finished = None
        deadline = time.monotonic() + 60  # only a hang reaches it
        while finished is None and (left := deadline - time.monotonic()) > 0:
            got = await boat.port.receive(left)
            if got is not None and isinstance(got.message, Finished):
                finished = got.message
        assert finished is not None and finished.depth_mm == 0
        assert rig.winch.status().at_home and rig.drum.motor() == (0, 0.0)
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, 30) == 0
