"""The sonar module over a real pty: start sequence, readings, stop, a pulled cable;
the simulated autopilot's frames carrying what it read; `simulate-sonar` as a process."""

from __future__ import annotations

import asyncio
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.drivers.sonar import ping
from cc_daemon.drivers.sonar.client import SonarReading
from cc_daemon.drivers.sonar.ping import DistanceSimple, PingStream
from cc_daemon.drivers.sonar.reader import SonarReader
from cc_daemon.sim.autopilot import Autopilot, AutopilotConfig
from cc_daemon.sim.mission import SonarReading as MissionReading
from cc_daemon.sim.mission import make_mission
from cc_daemon.sim.ping1d import Echo, FieldSounder, Ping1DDevice, Ping1DServer
from cc_daemon.sim.pty import PtyPair, make_raw
from cc_daemon.sim.sonar_chain import attach_sonar
from tests.test_sim_ping1d import ScriptedSounder


async def _until(check: Callable[[], bool], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, "timed out"
        await asyncio.sleep(0.02)


async def test_reader_starts_the_stream_keeps_readings_and_stops_on_exit(tmp_path: Path) -> None:
    got: list[SonarReading] = []
    with PtyPair(tmp_path / "ttySONAR") as pair:
        sounder = ScriptedSounder()
        server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(sounder))
        reader = SonarReader(str(pair.path), max_age_s=0.6, on_reading=got.append)
        task = asyncio.create_task(reader.run())
        try:
            await _until(lambda: len(got) >= 4)
            client = reader.client
            assert server.device.requests[:4] == [5, 1201, 1203, 1400]  # the manual's order
            assert (client.protocol_version, client.device_id) == ((1, 0, 0), 1)
            assert client.speed_of_sound_mm_s == 1_500_000
            assert [r.distance_mm for r in got] == [
                e.distance_mm for e in sounder.heard[: len(got)]
            ]
            current = reader.current()
            assert current.confidence_pct == 90 and current.distance_mm >= 4000
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        await _until(lambda: not server.device.streaming, timeout=30)
        assert server.device.requests[-1] == ping.CONTINUOUS_STOP
        # Nothing new for longer than max_age_s: the last reading ages out.
        await _until(lambda: reader.current().confidence_pct == 0, timeout=30)
        await server.close()


async def test_reader_survives_a_pulled_cable_and_starts_the_stream_again(tmp_path: Path) -> None:
    states: list[bool] = []
    with PtyPair(tmp_path / "ttySONAR") as pair:
        server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(ScriptedSounder()))
        reader = SonarReader(
            str(pair.path),
            reconnect_initial_s=0.05,
            reconnect_max_s=0.2,
            on_state=lambda up, _reason: states.append(up),
        )
        task = asyncio.create_task(reader.run())
        try:
            await _until(lambda: reader.client.readings >= 2)
            await server.close()
            pair.unplug()
            await _until(lambda: reader.losses == 1)
            pair.replug()
            server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(ScriptedSounder()))
            before = reader.client.readings
            await _until(lambda: reader.client.readings >= before + 2)
            assert server.device.requests[:4] == [5, 1201, 1203, 1400]
            assert states[:3] == [True, False, True]
            assert reader.client.starts >= 2
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await server.close()


async def test_a_silent_ping_gets_its_stream_started_again(tmp_path: Path) -> None:
    with PtyPair(tmp_path / "ttySONAR") as pair:
        device = Ping1DDevice(ScriptedSounder())
        server = await Ping1DServer.over_fd(pair.master_fd, device)
        reader = SonarReader(str(pair.path), restart_after_s=0.6)
        task = asyncio.create_task(reader.run())
        try:
            await _until(lambda: reader.client.readings >= 1)
            device.streaming = False  # as after a power cycle: it forgot
            device.requests.clear()
            await _until(lambda: device.streaming, timeout=3.0)
            assert device.requests[:4] == [5, 1201, 1203, 1400]
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await server.close()


async def test_the_autopilots_frames_carry_the_simulated_sonars_readings(tmp_path: Path) -> None:
    mission = make_mission(2, seed=4)
    autopilot = Autopilot(mission, AutopilotConfig(frame_period_s=0.25, boat_speed_m_s=3.0))
    t0 = time.monotonic()
    chain = await attach_sonar(
        autopilot, lambda: time.monotonic() - t0, port=None, workdir=tmp_path, seed=4
    )
    assert chain.simulated and chain.server is not None
    sent: list[Echo] = []
    sounder = chain.server.device.sounder
    assert isinstance(sounder, FieldSounder)

    def recording() -> Echo:
        echo = sounder()
        sent.append(echo)
        return echo

    chain.server.device.sounder = recording
    frames: list[Telemetry | StartMeasuring] = []
    try:
        await _until(lambda: len(sent) >= 2)
        while len(frames) < 8:
            for frame in autopilot.poll(time.monotonic() - t0):
                assert isinstance(frame, Telemetry | StartMeasuring)
                frames.append(frame)
            await asyncio.sleep(0.05)
    finally:
        await chain.close()
    echoes = {(e.distance_mm, e.confidence_pct) for e in sent}
    carried = [(f.sonar_distance_mm, f.sonar_confidence_pct) for f in frames]
    stale_ok = [c for c in carried if c not in echoes]
    # Every frame carries a reading the device sent (or, while the stream had
    # not caught up, that reading aged to confidence 0: never a made-up one).
    assert all(c[1] == 0 for c in stale_ok)
    assert len(stale_ok) <= 1
    assert len(set(carried)) >= 3  # the readings change as the boat moves
    for distance_mm, confidence in carried:
        if confidence:
            assert 2.0 < distance_mm / 1000 < 9.0  # the field's depths along the first leg


async def test_simulate_sonar_runs_alone_on_a_port(tmp_path: Path) -> None:
    with PtyPair(tmp_path / "ttyUSB9") as pair:
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "cc_daemon",
            "simulate-sonar",
            "--port",
            str(pair.path),
            "--seed",
            "2",
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
        )
        try:
            assert proc.stdout is not None
            ready = await asyncio.wait_for(proc.stdout.readline(), 30)
            assert b"simulated Ping1D on" in ready
            stream = PingStream()
            found: list[DistanceSimple] = []
            loop = asyncio.get_running_loop()
            arrived = asyncio.Event()

            def on_bytes() -> None:
                for envelope in stream.feed(os.read(pair.master_fd, 4096)):
                    if isinstance(envelope.event, DistanceSimple):
                        found.append(envelope.event)
                        arrived.set()

            loop.add_reader(pair.master_fd, on_bytes)
            try:
                os.write(pair.master_fd, ping.request(ping.DISTANCE_SIMPLE))
                await asyncio.wait_for(arrived.wait(), 10)
            finally:
                loop.remove_reader(pair.master_fd)
            assert found[0].confidence_pct >= 85  # holding still over a castable station
            assert 2.0 < found[0].distance_mm / 1000 < 9.0
        finally:
            proc.terminate()
            out, err = await asyncio.wait_for(proc.communicate(), 30)
        assert proc.returncode == 0, err
        assert b"1 requests, 1 readings sent" in out


async def test_simulate_sonar_creates_a_pty_where_the_port_does_not_exist(
    tmp_path: Path,
) -> None:
    # As simulate-sonde does: the path becomes a pty for a daemon's sonar.port.
    path = tmp_path / "ttyPING"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "cc_daemon", "simulate-sonar", "--port", str(path),
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert b"simulated Ping1D on" in await asyncio.wait_for(proc.stdout.readline(), 30)
        assert path.is_symlink()
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        try:
            make_raw(fd)
            os.write(fd, ping.request(ping.DISTANCE_SIMPLE))
            stream, found = PingStream(), []
            while not found:
                chunk = await asyncio.wait_for(asyncio.to_thread(os.read, fd, 4096), 10)
                found = [e for e in stream.feed(chunk) if isinstance(e.event, DistanceSimple)]
        finally:
            os.close(fd)
    finally:
        proc.terminate()
        _, err = await asyncio.wait_for(proc.communicate(), 30)
    assert proc.returncode == 0, err
    assert not path.exists() and not path.is_symlink()  # the pty and its link are gone


async def test_simulate_sonar_refuses_a_port_it_cannot_create(tmp_path: Path) -> None:
    proc = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "cc_daemon",
        "simulate-sonar",
        "--port",
        str(tmp_path / "no-such-dir" / "tty"),
        stderr=asyncio.subprocess.PIPE,
    )
    _, err = await asyncio.wait_for(proc.communicate(), 30)
    assert proc.returncode == 2
    assert b"cc-daemon simulate-sonar:" in err


def test_with_a_sonar_the_autopilot_reports_it_and_settles_before_m() -> None:
    mission = make_mission(1, seed=2)
    config = AutopilotConfig(frame_period_s=0.25, boat_speed_m_s=1000.0, settle_s=0.75)
    autopilot = Autopilot(mission, config)
    autopilot.sonar = lambda: MissionReading(1234, 88)
    frames = []
    t = 0.0
    while not any(isinstance(f, StartMeasuring) for f in frames):
        frames += autopilot.poll(t)
        t += 0.25
        assert t < 10
    assert all((f.sonar_distance_mm, f.sonar_confidence_pct) == (1234, 88) for f in frames)
    arrived = autopilot.logs[0].arrived_at
    assert arrived is not None
    first_m = next(i for i, f in enumerate(frames) if isinstance(f, StartMeasuring))
    assert (first_m * 0.25) - arrived >= 0.75  # T frames on station for the settle time
    assert all(isinstance(f, Telemetry) for f in frames[:first_m])


async def test_corrupt_bytes_from_the_sonar_are_counted_and_reading_goes_on(
    tmp_path: Path,
) -> None:
    with PtyPair(tmp_path / "ttySONAR") as pair:
        server = await Ping1DServer.over_fd(pair.master_fd, Ping1DDevice(ScriptedSounder()))
        reader = SonarReader(str(pair.path))
        task = asyncio.create_task(reader.run())
        try:
            await _until(lambda: reader.client.readings >= 1)
            spoiled = bytearray(ping.encode(ping.DISTANCE_SIMPLE, src=1, distance=1, confidence=1))
            spoiled[9] ^= 0x01
            server.write(b"\xff\x00BRB" + bytes(spoiled) + b"BR\xff\xff")
            before = reader.client.readings
            await _until(lambda: reader.client.readings >= before + 3)
            assert reader.client.bad_frames >= 2
            assert reader.client.latest.distance_mm >= 4000  # never the spoiled 1 mm
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            await server.close()
