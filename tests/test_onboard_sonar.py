"""Sonar on the Pi: the bottom choice (pure), and the daemon planning a cast from its own
Ping1D over a real pty, every reading journaled, the sonar's cable pulled and plugged back."""

from __future__ import annotations

import asyncio
import json
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from cc_daemon.config import Settings
from cc_daemon.core.cast.bottom import (
    AUTOPILOT,
    ONBOARD,
    Sounding,
    freshest_bottom,
    station_for_plan,
)
from cc_daemon.core.protocol import Ack, Finished
from cc_daemon.daemon.service import EXIT_OK, Daemon
from cc_daemon.drivers.sonar import ping
from cc_daemon.sim.ping1d import Echo, Ping1DDevice, Ping1DServer
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import FAST_CAST, DaemonProcess, merge, station


def _s(source: str, mm: int, conf: int, at: float) -> Sounding:
    return Sounding(source, mm, conf, at)


@pytest.mark.parametrize(
    ("soundings", "expected"),
    [
        ([], None),
        ([_s(AUTOPILOT, 3000, 90, 10.0)], 0),
        ([_s(AUTOPILOT, 3000, 90, 10.0), _s(ONBOARD, 2000, 95, 9.8)], 0),  # fresher wins
        ([_s(AUTOPILOT, 3000, 69, 10.0), _s(ONBOARD, 2000, 95, 9.8)], 1),  # not confident
        ([_s(AUTOPILOT, 3000, 0, 10.0), _s(ONBOARD, 2000, 95, 8.9)], None),  # too old
        ([_s(ONBOARD, 2000, 70, 9.0), _s(AUTOPILOT, 3000, 70, 9.5)], 1),
        ([_s(AUTOPILOT, 3000, 80, 9.5), _s(ONBOARD, 2000, 80, 9.5)], 0),  # a tie: the first
        ([_s(ONBOARD, 2000, 80, 10.5)], None),  # from the future: a clock mix-up, not trusted
    ],
)
def test_freshest_confident_bottom(soundings: list[Sounding], expected: int | None) -> None:
    best = freshest_bottom(soundings, 10.0, min_confidence=70, max_age_s=1.0)
    assert best == (None if expected is None else soundings[expected])


def test_station_for_plan_swaps_in_the_onboard_bottom_only_when_it_is_the_one() -> None:
    frame = station(sonar_mm=30_000, confidence=0)
    onboard = Sounding(ONBOARD, 2100, 96, 99.8)
    chosen, source = station_for_plan(frame, 100.0, onboard, min_confidence=70, max_age_s=1.0)
    assert source == ONBOARD
    assert (chosen.sonar_distance_mm, chosen.sonar_confidence_pct) == (2100, 96)
    assert chosen[:4] == frame[:4] and type(chosen) is type(frame)
    trusted = station(sonar_mm=4000, confidence=90)
    assert station_for_plan(trusted, 100.0, onboard, min_confidence=70, max_age_s=1.0) == (
        trusted,
        AUTOPILOT,
    )
    stale = Sounding(ONBOARD, 2100, 96, 98.0)
    assert station_for_plan(frame, 100.0, stale, min_confidence=70, max_age_s=1.0) == (frame, None)
    assert station_for_plan(frame, 100.0, None, min_confidence=70, max_age_s=1.0) == (frame, None)


async def _until(check: Callable[[], bool], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.02)


def _rows(db: Path, sql: str) -> list[tuple[object, ...]]:
    with sqlite3.connect(db) as conn:
        return conn.execute(sql).fetchall()


async def test_the_daemon_plans_from_its_own_sonar_and_journals_every_reading(
    tmp_path: Path,
) -> None:
    db = tmp_path / "j.db"
    with PtyPair(tmp_path / "ttyAP") as ap, PtyPair(tmp_path / "ttySONAR") as sonar_pty:
        device = Ping1DDevice(lambda: Echo(2100, 96))  # 2.1 m of water under the boat
        server = await Ping1DServer.over_fd(sonar_pty.master_fd, device)
        settings = Settings.model_validate(
            merge(
                FAST_CAST,
                {
                    "serial": {"port": str(ap.path)},
                    "store": {"path": str(db)},
                    "sonar": {
                        "port": str(sonar_pty.path),
                        "reconnect_initial_s": 0.05,
                        "reconnect_max_s": 0.2,
                    },
                },
            )
        )
        daemon = Daemon(settings)
        assert daemon.sonar is not None
        port = await FramePort.over_fd(ap.master_fd)
        task = asyncio.create_task(daemon.run())
        try:
            await asyncio.wait_for(daemon.ready.wait(), 30)
            reader = daemon.sonar.reader
            await _until(lambda: reader.client.readings >= 3)
            assert device.requests[:4] == [5, 1201, 1203, 1400]
            # The autopilot's own sonar has lost the bottom: confidence 0.
            await port.send(station(sonar_mm=30_000, confidence=0))
            first = await port.receive(30)
            assert first is not None and first.message == Ack(100)
            await _until(lambda: any(isinstance(r.message, Finished) for r in port.received), 60)
            # Pull the sonar's cable and plug it back: logged, reopened, streaming again.
            await server.close()
            sonar_pty.unplug()
            await _until(lambda: reader.losses == 1)
            sonar_pty.replug()
            device = Ping1DDevice(lambda: Echo(2200, 97))
            server = await Ping1DServer.over_fd(sonar_pty.master_fd, device)
            await _until(lambda: device.sent_readings >= 2)
        finally:
            daemon.request_shutdown()
            code = await asyncio.wait_for(task, 30)
            await port.close()
        await _until(lambda: not device.streaming)  # stopped on the way out
        await server.close()
    assert code == EXIT_OK
    [(plan_json, sonar_mm, conf, planned)] = _rows(
        db, "SELECT plan_json, sonar_distance_mm, sonar_confidence_pct, planned_depth_m FROM casts"
    )
    plan = json.loads(str(plan_json))
    assert (plan["limited_by"], plan["water_depth_m"]) == ("bottom", 2.1)
    assert planned == pytest.approx(2.1 - 0.5)  # not the 3 m target: the bottom is at 2.1 m
    assert (sonar_mm, conf) == (30_000, 0)  # the journal keeps the frame as it came
    readings = _rows(db, "SELECT port, distance_mm, confidence_pct FROM sonar_readings")
    assert len(readings) >= 5
    assert {r[0] for r in readings} == {str(tmp_path / "ttySONAR")}
    assert {(r[1], r[2]) for r in readings} == {(2100, 96), (2200, 97)}
    kinds = [k for (k,) in _rows(db, "SELECT kind FROM events ORDER BY id")]
    assert kinds.count("sonar_port_opened") == 2 and kinds.count("sonar_port_lost") == 1
    assert device.requests[-1] == ping.CONTINUOUS_STOP


def test_no_sonar_section_means_no_onboard_sonar(tmp_path: Path) -> None:
    daemon = Daemon(Settings.model_validate({"store": {"path": str(tmp_path / "j.db")}}))
    assert daemon.sonar is None


@pytest.mark.slow
async def test_the_daemon_process_plans_from_its_sonar_and_refuses_a_bad_sonar_setting(
    tmp_path: Path, make_daemon: Callable[..., DaemonProcess]
) -> None:
    with PtyPair(tmp_path / "ttySONAR") as sonar_pty:
        # 0.7 m of water: the daemon's own Ping says the station is too shallow.
        device = Ping1DDevice(lambda: Echo(700, 93))
        server = await Ping1DServer.over_fd(sonar_pty.master_fd, device)
        try:
            daemon = make_daemon({"sonar": {"port": str(sonar_pty.path)}})
            await daemon.start_and_connect()
            await _until(lambda: device.sent_readings >= 3)
            assert daemon.port is not None
            await daemon.port.send(station(sonar_mm=30_000, confidence=10))
            await daemon.expect(Ack, 3)
            finished = await daemon.expect(Finished, 3)  # skipped at once: no cast
            assert finished is not None and finished.message.depth_mm == 0
            daemon.send_signal()
            assert await daemon.wait_exit() == 0
        finally:
            await server.close()
        assert device.requests[-1] == ping.CONTINUOUS_STOP
    [(outcome, reason)] = _rows(daemon.db, "SELECT outcome, reason FROM casts")
    assert outcome == "skipped-shallow" and "sonar 0.7 m" in str(reason)
    assert _rows(daemon.db, "SELECT count(*) FROM sonar_readings")[0][0] >= 3
    bad = make_daemon({"sonar": {"port": str(tmp_path / "x"), "max_age_s": 0}}, name="bad")
    bad.start()
    assert await bad.wait_exit() == 2
    assert "sonar.max_age_s = 0" in bad.log_text()
