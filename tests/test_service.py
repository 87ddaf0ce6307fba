"""The service in-process, for paths a subprocess cannot reach: a bug in the
cast machine itself, and shutdown details."""

from __future__ import annotations

import asyncio
import contextlib
import gc
import socket
import sqlite3
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import structlog

from cc_daemon.config import Settings
from cc_daemon.core.cast.machine import CastMachine
from cc_daemon.core.protocol import (
    Ack,
    DepthReport,
    FaultReport,
    Finished,
    ProbePosition,
    ProbePositionRequest,
    Telemetry,
    encode,
)
from cc_daemon.core.winch.physics import LinePhysics
from cc_daemon.daemon.casting import EXIT_ROWS_LOST
from cc_daemon.daemon.service import EXIT_OK, EXIT_PROBE_MAY_BE_DOWN, Daemon
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.drivers.winch.simulated import SimulatedWinch
from cc_daemon.ground.clock import SystemClock
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from cc_daemon.store import Journal
from tests.daemonkit import (
    FAST_CAST,
    WAIT_S,
    collect_until,
    frames_before_reply,
    merge,
    next_frame,
    station,
)
from tests.waitkit import until


def is_finished(message: object) -> bool:
    return isinstance(message, Finished)


@pytest.fixture
async def rig(tmp_path: Path) -> AsyncIterator[tuple[Daemon, FramePort]]:
    pty = PtyPair(tmp_path / "tty")
    config: dict[str, Any] = merge(
        FAST_CAST, {"serial": {"port": str(pty.path)}, "store": {"path": str(tmp_path / "j.db")}}
    )
    daemon = Daemon(Settings.model_validate(config))
    port = await FramePort.over_fd(pty.master_fd)
    yield daemon, port
    await port.close()
    pty.close()


async def test_a_bug_in_the_cast_machine_stops_the_motor_and_keeps_alarming(
    rig: tuple[Daemon, FramePort], monkeypatch: pytest.MonkeyPatch
) -> None:
    daemon, port = rig
    real_step = CastMachine.step
    calls = 0

    def broken_step(self: CastMachine, now: float, status: Any) -> Any:
        nonlocal calls
        calls += 1
        if calls == 4:
            raise RuntimeError("bug")
        return real_step(self, now, status)

    monkeypatch.setattr(CastMachine, "step", broken_step)
    with structlog.testing.capture_logs() as logs:
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        await port.send(station())
        assert (await next_frame(port)).message == Ack(100)
        messages = [(await next_frame(port)).message for _ in range(4)]
        status = daemon.snapshot()
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_PROBE_MAY_BE_DOWN
    # Still reporting, never R-F; once the bug struck, as R-L (the fault, to the ground station).
    assert all(isinstance(m, DepthReport | FaultReport) for m in messages)
    assert isinstance(messages[-1], FaultReport) and isinstance(messages[-2], FaultReport)
    assert not any(isinstance(r.message, Finished) for r in port.received)
    assert status.phase != "idle"
    assert daemon._winch is not None and not daemon._winch.status().moving  # motor stopped
    criticals = [e for e in logs if e["log_level"] == "critical"]
    assert any("internal error" in e["event"] for e in criticals)
    assert sum("PROBE STATE UNKNOWN" in e["event"] for e in criticals) >= 2


async def test_a_second_ctrl_c_while_idle_is_a_clean_exit(rig: tuple[Daemon, FramePort]) -> None:
    daemon, port = rig
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
    await port.send(ProbePositionRequest(9))
    await next_frame(port, ProbePosition)
    daemon.request_shutdown()
    daemon.request_shutdown(immediate=True)
    assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK


async def test_start_up_objects_are_frozen_out_of_the_collectors_scans(
    rig: tuple[Daemon, FramePort],
) -> None:
    # A full collection over everything start-up built stalled the loop ~60 ms
    # under a pulse storm (docs/gpio-winch.md "The pulse storm").
    daemon, _ = rig
    gc.unfreeze()
    assert gc.get_freeze_count() == 0
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
    assert gc.get_freeze_count() > 1000
    daemon.request_shutdown()
    assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK


async def test_no_cast_starts_once_shutting_down(rig: tuple[Daemon, FramePort]) -> None:
    daemon, port = rig
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
    daemon._shutting_down = True  # as request_shutdown does, before the loop winds down
    await port.send(station())
    assert await frames_before_reply(port) == []  # no R-O: the autopilot must not count on us
    daemon.request_shutdown()
    assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
    assert daemon.snapshot().casts_completed == 0


class RecordingWinch(SimulatedWinch):
    """The simulated winch, remembering every command (to assert on afterwards)."""

    def __init__(self, speed_m_s: float = 1.0) -> None:
        super().__init__(LinePhysics(speed_m_s=speed_m_s, max_line_m=20.0), SystemClock())
        self.calls: list[str] = []

    def move_to(self, depth_m: float) -> None:
        self.calls.append(f"move_to {depth_m}")
        super().move_to(depth_m)

    def move_slowly_to(self, depth_m: float) -> None:
        self.calls.append(f"slowly {depth_m}")
        super().move_slowly_to(depth_m)

    def stop(self) -> None:
        self.calls.append("stop")
        super().stop()


def _settings(tmp_path: Path, port: Path, **extra: Any) -> Settings:
    config = merge(
        FAST_CAST, {"serial": {"port": str(port)}, "store": {"path": str(tmp_path / "j.db")}}
    )
    return Settings.model_validate(merge(config, extra))


async def test_after_an_internal_error_shutdown_never_restarts_the_motor(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_step = CastMachine.step
    calls = 0

    def broken_step(self: CastMachine, now: float, status: Any) -> Any:
        nonlocal calls
        calls += 1
        if calls == 3:
            raise RuntimeError("bug")
        return real_step(self, now, status)

    monkeypatch.setattr(CastMachine, "step", broken_step)
    with PtyPair(tmp_path / "tty") as pty:
        winch = RecordingWinch()
        daemon = Daemon(_settings(tmp_path, pty.path), winch=winch)
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        await port.send(station())
        await until(lambda: "stop" in winch.calls, what="the bug struck: the motor stopped")
        await next_frame(port, FaultReport)  # alarming
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_PROBE_MAY_BE_DOWN
        await port.close()
    failed_at = winch.calls.index("stop")  # the first stop is the one after the bug
    assert winch.calls[0] == "move_to 3.0"
    assert not any(call.startswith("move_to") for call in winch.calls[failed_at:])


async def test_a_crashing_background_task_does_not_touch_the_cast(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def crash(**_: Any) -> int:
        raise RuntimeError("housekeeping bug")

    monkeypatch.setattr("cc_daemon.daemon.housekeeping.flush_rate_limited", crash)
    with PtyPair(tmp_path / "tty") as pty, structlog.testing.capture_logs() as logs:
        daemon = Daemon(_settings(tmp_path, pty.path))
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        await port.send(station())
        finished = (await next_frame(port, Finished)).message
        daemon.request_shutdown()
        await asyncio.wait_for(task, WAIT_S)
        await port.close()
    assert isinstance(finished, Finished) and finished.depth_mm == 0
    assert any(e["event"] == "background task crashed; restarting it" for e in logs)


async def test_a_probe_found_down_is_brought_home_before_anything_else(tmp_path: Path) -> None:
    with PtyPair(tmp_path / "tty") as pty:
        winch = RecordingWinch(speed_m_s=10.0)
        daemon = Daemon(_settings(tmp_path, pty.path), winch=winch)
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        winch.move_to(15.0)  # lowered by hand, or left down by a previous run
        await until(lambda: winch.status().depth_m > 14.9, what="the probe lowered")
        await port.send(station())
        frames = [r.message for r in await collect_until(port, is_finished)]
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
        await port.close()
    assert isinstance(frames[0], Ack)
    assert isinstance(frames[-1], Finished) and frames[-1].depth_mm == 0
    assert any(isinstance(m, DepthReport) and m.depth_mm > 1000 for m in frames)
    assert "move_to 3.0" not in winch.calls  # no cast from a probe that was down
    with sqlite3.connect(tmp_path / "j.db") as db:
        rows = db.execute("SELECT outcome, reason FROM casts").fetchall()
    assert len(rows) == 1 and rows[0][0] == "aborted" and "down with no cast" in rows[0][1]


async def test_systemd_hears_ready_while_the_port_is_still_missing(tmp_path: Path) -> None:
    sock_path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(sock_path))
        server.settimeout(WAIT_S)
        daemon = Daemon(
            _settings(tmp_path, tmp_path / "no-such-tty"),
            notifier=SystemdNotifier(str(sock_path), watchdog=True),
        )
        task = asyncio.create_task(daemon.run())
        first = await asyncio.to_thread(server.recv, 1024)
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
        rest = []
        server.settimeout(0.2)  # the daemon has ended: all it said is queued already
        with contextlib.suppress(TimeoutError):
            while True:
                rest.append(server.recv(1024))
    # FAST_CAST allows the simulated winch outside --simulate: every STATUS says so.
    assert first.startswith(b"READY=1\nSTATUS=SIMULATED WINCH (sim): no probe moves; ")
    assert b" | opening " in first
    assert not daemon.ready.is_set()  # it never answered the autopilot: no port
    assert b"STOPPING=1" in rest


async def test_a_requested_shutdown_mid_cast_is_a_warning_not_an_error(
    rig: tuple[Daemon, FramePort],
) -> None:
    daemon, port = rig
    with structlog.testing.capture_logs() as logs:
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        await port.send(station())
        assert (await next_frame(port)).message == Ack(100)
        await next_frame(port, DepthReport)
        daemon.request_shutdown()  # systemctl restart, in the middle of the cast
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
    home = [e for e in logs if e["event"].startswith("cast ")]
    home = [e for e in home if "bringing the probe home" in e["event"]]
    assert [(e["log_level"], e["event"]) for e in home] == [
        ("warning", "cast cut short by a requested shutdown: bringing the probe home")
    ]
    assert home[0]["reason"] == "shutdown"
    # Nothing about the cast at error or worse (the simulated winch's banner is not it).
    assert not [e for e in logs if e["log_level"] in ("error", "critical") and "cast_id" in e]
    assert any(isinstance(r.message, Finished) for r in port.received)


async def test_a_station_repeated_within_the_rearm_window_says_so(
    rig: tuple[Daemon, FramePort],
) -> None:
    daemon, port = rig
    shoal = station(sonar_mm=500)  # refused at once: R-O, R-F, and the station is done
    with structlog.testing.capture_logs() as logs:
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        first_sent = time.monotonic()
        for _ in range(2):
            await port.send(shoal)
            await collect_until(port, is_finished)
        second_answered = time.monotonic()
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
    [repeat] = [e for e in logs if e["event"].startswith("station repeated")]
    assert (
        repeat["event"] == "station repeated within the re-arm window: repeating R-F, no new cast"
    )
    assert repeat["log_level"] == "info"
    assert repeat["rearm_s"] == 120.0
    # Since its R-F: no longer than from the first M to the second R-F, as the test saw them.
    assert 0 <= repeat["since_s"] <= round(second_answered - first_sent, 1) + 0.1


class DriftingWinch(SimulatedWinch):
    """At home by its switch while its count still says 42 mm (drift within tolerance)."""

    def __init__(self) -> None:
        super().__init__(LinePhysics(speed_m_s=10.0, max_line_m=20.0), SystemClock())

    def status(self) -> Any:
        status = super().status()
        return status._replace(depth_m=0.042) if status.at_home else status


async def test_r_f_always_carries_depth_0(tmp_path: Path) -> None:
    """R-F means home: depth 0 on the wire, whatever small figure the winch gives."""
    with PtyPair(tmp_path / "tty") as pty:
        daemon = Daemon(
            _settings(tmp_path, pty.path, cast={"target_depth_m": 1.0, "bottom_dwell_s": 0.1}),
            winch=DriftingWinch(),
        )
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        finishes: list[Finished] = []
        for shallow in (False, True, False):  # a cast, a skipped shoal, a repeated station
            await port.send(station(sonar_mm=300 if shallow else 30_000))
            finish = (await next_frame(port, Finished)).message
            assert isinstance(finish, Finished)
            finishes.append(finish)
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
        await port.close()
    assert len(finishes) == 3 and all(f.depth_mm == 0 for f in finishes)


async def test_rows_the_journal_could_put_nowhere_make_a_non_zero_exit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # The journal's directory is gone and no spill directory works (no state or
    # runtime directory here): rows at close are lost, and the exit status says so.
    pty = PtyPair(tmp_path / "tty")
    db = tmp_path / "gone" / "j.db"
    settings = Settings.model_validate(
        merge(FAST_CAST, {"serial": {"port": str(pty.path)}, "store": {"path": str(db)}})
    )
    journal = Journal(db)
    journal.open()
    daemon = Daemon(settings, journal=journal)
    try:
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_ROWS_LOST == 5
    finally:
        pty.close()
    assert journal.health().dropped_rows >= 2  # daemon_started, daemon_stopped
    assert "the journal lost rows during this run" in capsys.readouterr().out


async def test_a_burst_of_fixes_is_heard_whole_and_the_last_is_the_fix(
    rig: tuple[Daemon, FramePort],
) -> None:
    daemon, port = rig
    fixes = [Telemetry(n, -37260579, 404506308 + n, 702385, 8219, 100) for n in range(40)]
    burst = b"".join(map(encode, fixes[:30])) + encode(ProbePositionRequest(30))
    burst += b"".join(map(encode, fixes[30:]))
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
    await port.send(burst)  # one write: read in one or a few chunks, runs of T around the S
    got = await next_frame(port)
    assert isinstance(got.message, ProbePosition)
    assert got.message.timestamp_s == 30  # the S's own time, whatever came before it
    await until(lambda: daemon.frames_in >= 41, what="the T after the S read")
    status = daemon.snapshot()
    daemon.request_shutdown()
    assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
    assert status.frames_in == 41 and status.corrupt_frames == 0
    assert status.last_fix is not None and status.last_fix.message == fixes[-1]
    with sqlite3.connect(daemon.settings.store.path or "") as db:
        kept = db.execute("SELECT ap_timestamp_s FROM fixes").fetchall()
        dropped = db.execute(
            "SELECT sum(json_extract(detail_json, '$.dropped')) FROM events"
            " WHERE kind = 'telemetry_thinned'"
        ).fetchone()[0]
    assert (39,) in kept  # the latest, kept at the end; every other one kept or counted
    assert len(kept) + (dropped or 0) == 40


async def test_a_broken_fix_inside_a_burst_is_counted_corrupt_and_the_rest_heard(
    rig: tuple[Daemon, FramePort],
) -> None:
    # The daemon reads P-T in runs (Parser.events_in_runs): a frame broken in the
    # middle of a burst ends the run, is judged alone, and the fixes after it are
    # a run of their own; the P-S after them is still answered with its own time.
    daemon, port = rig
    fixes = [Telemetry(n, -37260579, 404506308 + n, 702385, 8219, 100) for n in range(20)]
    frames = [encode(fix) for fix in fixes]
    frames[10] = frames[10][:24] + bytes([frames[10][24] ^ 0x01])  # checksum off
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
    await port.send(b"".join(frames) + encode(ProbePositionRequest(20)))
    got = await next_frame(port)
    assert isinstance(got.message, ProbePosition)
    assert got.message.timestamp_s == 20
    status = daemon.snapshot()
    daemon.request_shutdown()
    assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
    assert status.frames_in == 20 and status.corrupt_frames == 1  # 19 fixes and the S
    assert status.last_fix is not None and status.last_fix.message == fixes[-1]
