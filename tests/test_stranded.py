"""A probe that may be down and cannot come home: R-L to the ground station, never
R-F, until the winch verifies home again (issue 19). In-process daemon on the GPIO
winch over mock pins and the simulated drum; the autopilot's end of a real pty."""

from __future__ import annotations

import asyncio
import json
import os
import sqlite3
import time
from pathlib import Path
from typing import Any

import pytest
import structlog

from cc_daemon.cli.app import main
from cc_daemon.cli.status.view import status_lines
from cc_daemon.core.protocol import Ack, DepthReport, FaultReport, Finished, ProbeUp
from cc_daemon.daemon.control_server import Peer, authorised
from cc_daemon.daemon.service import EXIT_OK, EXIT_PROBE_MAY_BE_DOWN, Daemon
from cc_daemon.daemon.status_report import status_document
from cc_daemon.sim.drum import DrumFaults
from cc_daemon.sim.port import FramePort, Received
from cc_daemon.sim.pty import PtyPair
from cc_daemon.store import Journal
from tests.daemonkit import WAIT_S, collect_until, next_frame, nth, station
from tests.gpiokit import gpio_rig
from tests.test_gpio_daemon import Boat, _boat, _settings
from tests.waitkit import until


async def _until(boat: Boat, phase: str, timeout: float = WAIT_S) -> list[Received]:
    frames: list[Received] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and boat.daemon.snapshot().phase != phase:
        got = await boat.port.receive(0.3)
        if got is not None:
            frames.append(got)
    assert boat.daemon.snapshot().phase == phase, [r.message for r in frames]
    return frames


def _events(tmp_path: Path) -> list[tuple[str, str]]:
    with sqlite3.connect(tmp_path / "j.db") as db:
        return db.execute("SELECT kind, detail_json FROM events ORDER BY id").fetchall()


async def test_stranded_hauling_in_sends_r_l_until_the_stick_brings_it_home(
    tmp_path: Path,
) -> None:
    async with gpio_rig(faults=DrumFaults(jam_in_at_m=1.5)) as rig, _boat(tmp_path, rig) as boat:
        with structlog.testing.capture_logs() as logs:
            await boat.port.send(station())
            before = await _until(boat, "stranded")
            assert not any(isinstance(r.message, Finished) for r in before)
            stranded = await collect_until(boat.port, nth(FaultReport, 3))
            # In place of R-M: R-L every period, carrying the depth the probe is stuck at
            # (an R-M sent before the stranding may still have been on its way).
            faults = [r.message for r in stranded]
            faults = faults[[type(m) for m in faults].index(FaultReport) :]
            assert len(faults) == 3 and all(isinstance(m, FaultReport) for m in faults)
            assert all(1300 <= m.depth_mm <= 1700 for m in faults)  # type: ignore[union-attr]
            doc: dict[str, Any] = status_document(boat.daemon.status_inputs())
            reported = doc["cast"]["fault_reported"]
            assert reported["fault"].startswith("stall") and reported["r_l_sent"] >= 2
            assert 1.3 <= reported["depth_m"] <= 1.7
            words = dict(status_lines(doc))  # what `cc-daemon status` prints
            assert "R-L sent to the autopilot" in words["STRANDED"]
            # The line is freed; the safety pilot holds the stick up: home, then R-F, depth 0.
            rig.drum.faults = DrumFaults()
            finished: Finished | None = None
            deadline = time.monotonic() + WAIT_S
            while finished is None and time.monotonic() < deadline:
                await boat.port.send(ProbeUp(7))
                got = await boat.port.receive(0.5)
                while got is not None and finished is None:
                    if isinstance(got.message, Finished):
                        finished = got.message
                    got = await boat.port.receive(0.05)
            assert finished is not None and finished.depth_mm == 0
            assert rig.winch.status().at_home
            boat.daemon.request_shutdown()
            assert await asyncio.wait_for(boat.task, WAIT_S) == EXIT_OK
    criticals = [e for e in logs if e["log_level"] == "critical"]
    assert any("PROBE NOT HOME" in e["event"] for e in criticals)
    kinds = [kind for kind, _ in _events(tmp_path)]
    assert kinds.index("cast_stranded") < kinds.index("fault_reported")
    assert kinds.index("fault_reported") < kinds.index("stranded_cleared")
    assert kinds.count("fault_reported") == 1  # once per stranding, not every period


async def test_a_winch_that_failed_to_home_refuses_every_cast_with_r_l(tmp_path: Path) -> None:
    # The probe 2 m down at start, not homed (home_at_start off: the winch's own
    # start-up fault; the witnesses' "homing failed" is refused the same way).
    async with (
        gpio_rig(line_m=2.0, start_up=False, home_at_start=False) as rig,
        _boat(tmp_path, rig) as boat,
    ):
        status = rig.winch.status()
        assert status.fault is not None and not status.at_home
        await boat.port.send(station())
        first = await next_frame(boat.port)
        second = await next_frame(boat.port)
        assert first.message == Ack(100)
        # R-O, then the fault at once: no cast, the motor never runs.
        assert isinstance(second.message, FaultReport)
        more = [await next_frame(boat.port) for _ in range(2)]
        assert all(isinstance(r.message, FaultReport) for r in more)
        assert rig.drum.motor() == (0, 0.0)
        assert boat.daemon.snapshot().phase == "stranded"
        # The autopilot asks where the probe is: answered; a second M starts nothing
        # (the R-L of the period may come before the answer).
        await boat.port.send(station(timestamp=130))
        again = await collect_until(boat.port, lambda m: not isinstance(m, FaultReport))
        assert again[-1].message == Ack(130)
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, WAIT_S) == EXIT_PROBE_MAY_BE_DOWN
    received = [r.message for r in boat.port.received]
    assert not any(isinstance(m, Finished | DepthReport) for m in received)
    kinds = [kind for kind, _ in _events(tmp_path)]
    assert "cast_refused" in kinds and "fault_reported" in kinds
    with sqlite3.connect(tmp_path / "j.db") as db:
        assert db.execute("SELECT count(*) FROM samples WHERE phase != 'stranded'").fetchone() == (
            0,
        )


async def test_an_operator_releases_a_station_the_winch_cannot_verify(tmp_path: Path) -> None:
    # A probe jammed at 1.5 m hauling in: stranded, R-L. The operator has seen it on
    # board (say the switch is broken): `cc-daemon release` through the control socket.
    # Its reason carries a terminal's escape and a bidi override (issue 27): kept as
    # printable escapes wherever it is stored.
    status_path = tmp_path / "run" / "status.sock"
    status_path.parent.mkdir()
    settings = _settings(tmp_path, tmp_path / "tty")
    settings = settings.model_copy(
        update={"status": settings.status.model_copy(update={"path": status_path})}
    )
    control = status_path.with_name("control.sock")
    async with gpio_rig(faults=DrumFaults(jam_in_at_m=1.5)) as rig:
        with PtyPair(tmp_path / "tty") as pty:
            daemon = Daemon(settings, winch=rig.winch)
            port = await FramePort.over_fd(pty.master_fd)
            task = asyncio.create_task(daemon.run())
            await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
            boat = Boat(daemon, port, task)
            reason = "probe seen on deck \x1b]0;pwned\x07 \u202eevil"
            args = ["release", "--reason", reason, "--socket", str(control)]
            # The control socket is bound by its own task.
            await until(control.exists, what="the control socket bound")
            assert oct(control.stat().st_mode & 0o777) == "0o660"
            # Nothing stranded yet: refused, and nothing is sent.
            assert await asyncio.to_thread(main, args) == 1
            await port.send(station())
            await _until(boat, "stranded")
            assert await asyncio.to_thread(main, args) == 0
            got = await next_frame(port, Finished)
            assert got.message.depth_mm == 0  # type: ignore[union-attr]
            assert daemon.snapshot().phase == "idle"
            daemon.request_shutdown()
            # The winch still cannot verify home: the exit says so.
            assert await asyncio.wait_for(task, WAIT_S) == EXIT_PROBE_MAY_BE_DOWN
            await port.close()
    kept = "probe seen on deck \\x1b]0;pwned\\x07 \\u202eevil"
    events = dict(_events(tmp_path))
    assert json.loads(events["operator_release"])["reason"] == kept
    with sqlite3.connect(tmp_path / "j.db") as db:
        [(outcome, reason)] = db.execute("SELECT outcome, reason FROM casts").fetchall()
    assert outcome == "aborted" and reason == f"released by an operator: {kept}"
    assert reason.isprintable()


def test_only_root_the_daemon_s_user_or_the_socket_s_group_may_release() -> None:
    me = os.getuid()
    assert authorised(Peer(1, me, 4242), socket_gid=4343)
    assert authorised(Peer(1, 0, 4242), socket_gid=4343)
    stranger = 54321 if me != 54321 else 54322  # no such user: no supplementary groups
    assert authorised(Peer(1, stranger, 4343), socket_gid=4343)  # its primary group
    assert not authorised(Peer(1, stranger, 4242), socket_gid=4343)


async def test_a_restart_that_cannot_verify_home_holds_the_interrupted_station_with_r_l(
    tmp_path: Path,
) -> None:
    # The previous run died mid-cast (no end, no daemon_stopped) with the probe 2 m down.
    journal = Journal(tmp_path / "j.db")
    journal.open()
    cast_id = journal.start_cast(station(), planned_depth_m=3.0, mode="continuous", plan={})
    journal.record_sample(cast_id, 2.0, "descending")
    journal.close()
    # This run's winch is not homed (home_at_start off): it cannot verify home.
    async with (
        gpio_rig(line_m=2.0, start_up=False, home_at_start=False) as rig,
        _boat(tmp_path, rig) as boat,
    ):
        # No M comes: the firmware is still waiting at the station. R-L, never R-F.
        got = [await next_frame(boat.port) for _ in range(2)]
        assert all(isinstance(r.message, FaultReport) for r in got)
        assert boat.daemon.snapshot().phase == "stranded"
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, WAIT_S) == EXIT_PROBE_MAY_BE_DOWN
    assert not any(isinstance(r.message, Finished) for r in boat.port.received)
    events = _events(tmp_path)
    kinds = [kind for kind, _ in events]
    assert "daemon_died" in kinds
    interrupted = json.loads(dict(events)["cast_interrupted"])
    assert interrupted == {"cast_id": cast_id, "last_depth_m": 2.0, "samples": 1}
    recovered = json.loads(dict(events)["cast_recovered"])
    assert recovered == {"cast_id": cast_id, "rf_sent": False, "held_by_r_l": True}


async def test_winch_home_with_the_daemon_running_hauls_a_stranded_probe_in(
    tmp_path: Path,
) -> None:
    status_path = tmp_path / "run" / "status.sock"
    status_path.parent.mkdir()
    config = tmp_path / "cc-daemon.toml"
    config.write_text(f'[status]\npath = "{status_path}"\n')
    settings = _settings(tmp_path, tmp_path / "tty")
    settings = settings.model_copy(
        update={"status": settings.status.model_copy(update={"path": status_path})}
    )
    async with gpio_rig(faults=DrumFaults(jam_in_at_m=1.5)) as rig:
        with PtyPair(tmp_path / "tty") as pty:
            daemon = Daemon(settings, winch=rig.winch)
            port = await FramePort.over_fd(pty.master_fd)
            task = asyncio.create_task(daemon.run())
            await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
            args = ["winch", "home", "--config", str(config)]
            await port.send(station())
            await _until(Boat(daemon, port, task), "stranded")
            # Still jammed: the daemon tries, stalls again, stays stranded; no R-F.
            stalls = rig.kinds().count("winch_fault")
            assert await asyncio.to_thread(main, args) == 0
            await until(
                lambda: rig.kinds().count("winch_fault") > stalls and not rig.winch.status().moving,
                what="the haul stalled again",
            )
            assert daemon.snapshot().phase == "stranded"
            rig.drum.faults = DrumFaults()  # the line freed
            assert await asyncio.to_thread(main, args) == 0
            got = await next_frame(port, Finished)
            assert got.message.depth_mm == 0  # type: ignore[union-attr]
            assert rig.winch.status().at_home
            daemon.request_shutdown()
            assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
            await port.close()
    kinds = [kind for kind, _ in _events(tmp_path)]
    assert kinds.count("operator_haul_in") == 2 and "stranded_cleared" in kinds


def test_the_control_socket_is_named_after_its_status_socket() -> None:
    from cc_daemon.daemon.control_server import control_path

    assert control_path(Path("/run/cc-daemon/status.sock")) == Path("/run/cc-daemon/control.sock")
    # Two daemons started by hand on two journals in one directory: two sockets.
    assert control_path(Path("/data/a.db.status.sock")) == Path("/data/a.db.control.sock")
    assert control_path(Path("/data/custom.sock")) == Path("/data/custom.sock.control.sock")


def _died_mid_cast(tmp_path: Path, depth_m: float) -> int:
    """A journal whose previous run died mid-cast (no end, no daemon_stopped)."""
    journal = Journal(tmp_path / "j.db")
    journal.open()
    cast_id = journal.start_cast(station(), planned_depth_m=3.0, mode="continuous", plan={})
    journal.record_sample(cast_id, depth_m, "ascending")
    journal.close()
    return cast_id


async def test_a_restart_with_a_shorted_switch_and_the_probe_down_sends_no_r_f(
    tmp_path: Path,
) -> None:
    # The previous run died with the probe 2 m down; the switch is shorted (closed).
    # A fresh process has no count: the switch alone would be home on one witness,
    # and R-F would release the boat with the probe 2 m down. The journal's depth
    # stands until a haul brings the probe home: R-L, and the operator is told why.
    cast_id = _died_mid_cast(tmp_path, 2.0)
    async with (
        gpio_rig(line_m=2.0, start_up=False, faults=DrumFaults(switch_stuck_closed=True)) as rig,
        _boat(tmp_path, rig) as boat,
    ):
        got = [await next_frame(boat.port) for _ in range(2)]
        assert all(isinstance(r.message, FaultReport) for r in got)
        status = rig.winch.status()
        assert not status.at_home and status.depth_m == pytest.approx(2.0)
        assert status.fault is not None and "cannot be home" in status.fault
        assert rig.drum.motor() == (0, 0.0)
        assert ("winch_left_down", {"left_down_m": 2.0}) in rig.events
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, WAIT_S) == EXIT_PROBE_MAY_BE_DOWN
    assert not any(isinstance(r.message, Finished) for r in boat.port.received)
    recovered = json.loads(dict(_events(tmp_path))["cast_recovered"])
    assert recovered == {"cast_id": cast_id, "rf_sent": False, "held_by_r_l": True}


async def test_a_restart_with_the_probe_down_hauls_it_home_and_then_sends_r_f(
    tmp_path: Path,
) -> None:
    # The same death, a sound switch: the start-up homing hauls the probe in, the
    # switch closes at the end of a counted haul, and only then the station is freed.
    cast_id = _died_mid_cast(tmp_path, 2.0)
    async with gpio_rig(line_m=2.0, start_up=False) as rig, _boat(tmp_path, rig) as boat:
        got = await next_frame(boat.port)
        assert isinstance(got.message, Finished)
        assert rig.winch.status().at_home and rig.drum.line_m < 0.1
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, WAIT_S) == EXIT_OK
    recovered = json.loads(dict(_events(tmp_path))["cast_recovered"])
    assert recovered == {"cast_id": cast_id, "rf_sent": True}
