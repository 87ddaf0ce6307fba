"""Whole casts through the daemon on the GPIO winch (mock pins, simulated drum), the
simulated-winch gate, the winch's provenance in the journal and the exports, and
`cc-daemon winch`."""

from __future__ import annotations

import asyncio
import contextlib
import csv
import io
import json
import socket
import sqlite3
import subprocess
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.app import main
from cc_daemon.config import Settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.core.protocol import DepthReport, Finished
from cc_daemon.daemon.service import EXIT_PROBE_MAY_BE_DOWN, Daemon
from cc_daemon.daemon.simgate import backend_name, check_backend_allowed, simulation_warning
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.export import csv as csv_export
from cc_daemon.export import geojson
from cc_daemon.export.provenance import of_casts
from cc_daemon.sim.devices import SIMULATORS
from cc_daemon.sim.drum import DrumFaults
from cc_daemon.sim.port import FramePort, Received
from cc_daemon.sim.pty import PtyPair
from cc_daemon.store import Journal, JournalReader
from tests.daemonkit import FAST_CAST, merge, station
from tests.gpiokit import GpioRig, enable_history, gpio_rig
from tests.waitkit import until


def _settings(tmp_path: Path, port: Path) -> Settings:
    config = merge(
        FAST_CAST,
        {
            "serial": {"port": str(port)},
            "store": {"path": str(tmp_path / "j.db")},
            "winch": {"backend": "gpio", "gpio": {"pin_factory": "mock"}},
            "cast": {"bottom_dwell_s": 0.5},
        },
    )
    return Settings.model_validate(config)


class Boat:
    """The daemon in-process on the rig's winch, and the autopilot's end of the pty."""

    def __init__(self, daemon: Daemon, port: FramePort, task: asyncio.Task[int]) -> None:
        self.daemon = daemon
        self.port = port
        self.task = task

    async def cast(self, timeout: float = 20.0) -> list[Received]:
        await self.port.send(station())
        frames: list[Received] = []
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            got = await self.port.receive(left)
            if got is None:
                break
            frames.append(got)
            if isinstance(got.message, Finished):
                break
        return frames


@contextlib.asynccontextmanager
async def _boat(tmp_path: Path, rig: GpioRig) -> AsyncIterator[Boat]:
    with PtyPair(tmp_path / "tty") as pty:
        daemon = Daemon(_settings(tmp_path, pty.path), winch=rig.winch)
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), 30)
        try:
            yield Boat(daemon, port, task)
        finally:
            if not task.done():
                daemon.request_shutdown(immediate=True)
            await asyncio.wait({task}, timeout=30)
            await port.close()


def _cast_rows(tmp_path: Path) -> list[tuple[Any, ...]]:
    with sqlite3.connect(tmp_path / "j.db") as db:
        return db.execute("SELECT outcome, reason, winch_backend, simulated FROM casts").fetchall()


async def test_a_stall_going_down_aborts_and_brings_the_probe_home(tmp_path: Path) -> None:
    async with gpio_rig(faults=DrumFaults(jam_at_m=1.0)) as rig, _boat(tmp_path, rig) as boat:
        frames = await boat.cast()
        last = frames[-1].message
        assert isinstance(last, Finished) and last.depth_mm == 0
        assert rig.winch.status().at_home and rig.drum.motor() == (0, 0.0)
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, 30) == 0
    [(outcome, reason, backend, simulated)] = _cast_rows(tmp_path)
    assert outcome == "aborted" and "stall: no drum pulse" in reason
    assert (backend, simulated) == ("gpio-mock", 1)


async def test_a_stall_hauling_in_strands_the_probe_loudly(tmp_path: Path) -> None:
    async with gpio_rig(faults=DrumFaults(jam_in_at_m=1.5)) as rig, _boat(tmp_path, rig) as boat:
        await boat.port.send(station())
        reports: list[int] = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and boat.daemon.snapshot().phase != "stranded":
            got = await boat.port.receive(0.5)
            if got is not None and isinstance(got.message, DepthReport):
                reports.append(got.message.depth_mm)
        assert boat.daemon.snapshot().phase == "stranded"
        fault = boat.daemon.snapshot().winch_fault
        assert fault is not None and fault.startswith("stall")
        assert rig.drum.motor() == (0, 0.0)
        more = [await boat.port.receive(1.5) for _ in range(2)]
        assert not any(r is not None and isinstance(r.message, Finished) for r in more)
        boat.daemon.request_shutdown()
        assert await asyncio.wait_for(boat.task, 30) == EXIT_PROBE_MAY_BE_DOWN


async def test_an_immediate_stop_mid_descent_switches_the_motor_off_at_once(
    tmp_path: Path,
) -> None:
    async with gpio_rig() as rig, _boat(tmp_path, rig) as boat:
        await boat.port.send(station())
        async with asyncio.timeout(30):
            while rig.drum.motor()[0] != 1:
                rig.winch.status()  # what wait_change waits for is a change after this
                await rig.winch.wait_change(0.05)
        await rig.until(lambda: rig.drum.line_m > 0.3)
        assert rig.drum.motor()[0] == 1  # going down
        stopped_at = time.monotonic()
        boat.daemon.request_shutdown(immediate=True)  # a second Ctrl-C
        off = enable_history(rig)[-1]  # read before this test lets the loop run again
        assert off[1] == 0.0 and off[0] >= stopped_at
        assert await asyncio.wait_for(boat.task, 30) == EXIT_PROBE_MAY_BE_DOWN
        assert 0.2 < rig.drum.line_m < 3.0  # stopped where it was, not hauled


# ---------------------------------------------------------------- the gate


def test_a_simulated_winch_needs_to_be_asked_for_outside_simulation() -> None:
    sim = Settings()
    with pytest.raises(
        ConfigError, match=r'winch.backend = "sim" \(default\): a simulated winch.*--simulate$'
    ):
        check_backend_allowed(sim)
    mock = Settings.model_validate({"winch": {"backend": "gpio", "gpio": {"pin_factory": "mock"}}})
    with pytest.raises(ConfigError, match=r'winch.gpio.pin_factory = "mock" \(given\)'):
        check_backend_allowed(mock)
    check_backend_allowed(Settings.model_validate({"winch": {"backend": "gpio"}}))
    allowed = Settings.model_validate({"winch": {"sim": {"allow_outside_simulation": True}}})
    check_backend_allowed(allowed)
    assert simulation_warning(allowed) is not None
    assert simulation_warning(sim) is None  # refused, never announced
    assert [backend_name(s) for s in (sim, mock)] == ["sim", "gpio-mock"]


def test_the_daemon_refuses_the_default_simulated_winch_with_exit_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    for name in [n for n in __import__("os").environ if n.startswith("CC_DAEMON_")]:
        monkeypatch.delenv(name)
    assert main(["--port", str(tmp_path / "tty"), "--db", str(tmp_path / "j.db")]) == 2
    err = capsys.readouterr().err
    assert "winch.sim.allow_outside_simulation = true" in err
    assert 'winch.backend = "sim" (default)' in err and "cc-daemon --simulate" in err
    assert main(["--winch", "gpio-mock", "--db", str(tmp_path / "j.db")]) == 2
    assert 'winch.gpio.pin_factory = "mock" (from --winch)' in capsys.readouterr().err
    assert not (tmp_path / "j.db").exists()


# ---------------------------------------------------------------- provenance


def _journal_with_a_cast(path: Path, **winch: Any) -> None:
    journal = Journal(path, **winch)
    journal.open()
    cast_id = journal.start_cast(station(), planned_depth_m=2.0, mode="continuous", plan={})
    journal.record_sample(cast_id, 1.0, "descending")
    journal.end_cast(cast_id, outcome="completed", reached_depth_m=2.0)
    journal.close()


def test_every_export_says_which_winch_and_whether_simulated(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    _journal_with_a_cast(db, winch_backend="gpio", simulated=False)
    _journal_with_a_cast(db, winch_backend="sim", simulated=True)
    with JournalReader(db) as reader:
        casts = reader.casts()
        samples = reader.samples()
    assert [(c.winch_backend, c.simulated) for c in casts] == [("gpio", False), ("sim", True)]
    out = io.StringIO()
    csv_export.write_samples(samples[:1], out, provenance=of_casts(casts[:1]).comment())
    first, rest = out.getvalue().split("\r\n", 1)
    assert first == "# winch_backend: gpio; simulated: no"
    assert len(list(csv.DictReader(io.StringIO(rest)))) == 1
    assert of_casts(casts).comment() == "# winch_backend: gpio, sim; simulated: mixed"
    features = json.loads(_geojson(casts))["features"]
    stations = [f["properties"] for f in features if f["properties"]["feature"] == "station"]
    assert [(p["winch_backend"], p["simulated"]) for p in stations] == [
        ("gpio", False),
        ("sim", True),
    ]
    netcdf4 = pytest.importorskip("netCDF4")
    from cc_daemon.export import netcdf

    netcdf.write(casts, samples, tmp_path / "casts.nc")
    with netcdf4.Dataset(str(tmp_path / "casts.nc")) as nc:
        assert (nc.winch_backend, nc.simulated) == ("gpio, sim", "mixed")


def _geojson(casts: Any) -> str:
    out = io.StringIO()
    geojson.write(casts, [], out)
    return out.getvalue()


def test_sessions_record_the_winch_and_old_rows_say_unknown(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    _journal_with_a_cast(db)  # a journal not told: NULL, "unknown"
    _journal_with_a_cast(db, winch_backend="gpio", simulated=False)
    with sqlite3.connect(db) as conn:
        rows = conn.execute("SELECT winch_backend, simulated FROM sessions ORDER BY id")
        assert rows.fetchall() == [(None, None), ("gpio", 0)]
    with JournalReader(db) as reader:
        assert of_casts(reader.casts()[:1]).comment() == (
            "# winch_backend: unknown; simulated: unknown"
        )


# ---------------------------------------------------------------- cc-daemon winch


def test_the_winch_command_jogs_and_prints_line_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    config = tmp_path / "c.toml"
    config.write_text("[winch.gpio]\nline_speed_m_s = 2.0\nadc = true\n")
    assert main(["winch", "--mock", "--config", str(config), "down", "--metres", "1.0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("line out   0.000 m  count     0  switch closed  current")
    assert "line out   0.990 m  count     7  switch open" in lines[-1]
    assert main(["winch", "--mock", "--config", str(config), "status"]) == 0
    assert "supply 12.00 V" in capsys.readouterr().out
    assert main(["winch", "--mock", "up", "--seconds", "-1"]) == 2
    assert "--seconds -1: allowed > 0" in capsys.readouterr().err


# ---------------------------------------------------------------- --simulate --winch gpio-mock


def test_simulate_runs_a_survey_on_the_gpio_winch_with_mock_pins(tmp_path: Path) -> None:
    db = tmp_path / "demo.db"
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("CC_DAEMON_")}
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "cc_daemon",
            "--simulate",
            "--winch",
            "gpio-mock",
            "--stations",
            "1",
            "--plain",
            "--db",
            str(db),
        ],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=240,  # a whole survey in real time: far longer on a loaded machine
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr
    assert "SURVEY OK" in done.stdout
    assert "winch home: limit switch closed" in done.stdout
    with JournalReader(db) as reader:
        casts = reader.casts()
    assert [(c.outcome, c.winch_backend, c.simulated) for c in casts] == [
        ("completed", "gpio-mock", True)
    ]


async def test_the_daemon_homes_a_probe_left_down_before_it_says_ready(tmp_path: Path) -> None:
    sock_path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(sock_path))
        server.settimeout(10)
        async with gpio_rig(line_m=1.2, start_up=False) as rig:
            assert not rig.winch.status().at_home
            daemon = Daemon(
                _settings(tmp_path, tmp_path / "no-such-tty"),
                winch=rig.winch,
                notifier=SystemdNotifier(str(sock_path)),
            )
            task = asyncio.create_task(daemon.run())
            first = await asyncio.to_thread(server.recv, 1024)
            second = await asyncio.to_thread(server.recv, 1024)
            home_when_ready = rig.winch.status().at_home
            daemon.request_shutdown()
            assert await asyncio.wait_for(task, 30) == 0
    assert first.endswith(b"homing the winch")
    assert second.startswith(b"READY=1\n")
    assert home_when_ready and rig.drum.line_m <= 0.05
    assert rig.kinds()[:2] == ["winch_homing", "winch_homed"]


async def test_a_stuck_daemon_loop_stops_the_motor_and_the_fault_is_journaled(
    tmp_path: Path,
) -> None:
    with PtyPair(tmp_path / "tty") as pty:
        settings = _settings(tmp_path, pty.path)
        gpio = {"pin_factory": "mock", "loop_watchdog_s": 0.3, "line_speed_m_s": 0.5}
        settings = Settings.model_validate(merge(settings.model_dump(), {"winch": {"gpio": gpio}}))
        # The daemon builds the mock winch; the drum behind it is the simulator's, handed in.
        daemon = Daemon(settings, simulators=SIMULATORS)
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), 30)
        await port.send(station())
        # The loop stuck early in a descent of about 6 s, while the motor surely runs: a
        # stop at the target (on the drum's thread) is seconds away, the watchdog's trip
        # 0.3 s. Seen by the daemon's own status, not after a guessed time.
        await until(
            lambda: (
                daemon.snapshot().phase == "descending" and daemon.snapshot().probe_depth_m >= 0.2
            ),
            what="the descent under way",
        )
        time.sleep(2.0)  # noqa: ASYNC251 - the daemon's loop is stuck, the motor runs on
        frames = []
        while (got := await port.receive(10)) is not None:
            frames.append(got.message)
            if isinstance(got.message, Finished):
                break
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, 30) == 0
        await port.close()
    assert isinstance(frames[-1], Finished) and frames[-1].depth_mm == 0  # aborted, home
    with sqlite3.connect(tmp_path / "j.db") as db:
        faults = [
            json.loads(d)["fault"]
            for (d,) in db.execute("SELECT detail_json FROM events WHERE kind = 'winch_fault'")
        ]
        outcome = db.execute("SELECT outcome FROM casts").fetchone()[0]
    assert any(f.startswith("loop watchdog: the event loop was silent") for f in faults)
    assert outcome == "aborted"


async def test_the_simulated_winchs_fault_keys_jam_the_mock_drum(tmp_path: Path) -> None:
    with PtyPair(tmp_path / "tty") as pty:
        settings = _settings(tmp_path, pty.path)
        extra = {
            "gpio": {"line_speed_m_s": 2.0, "stall_timeout_s": 0.5},
            "sim": {"stall_at_m": 1.0},
        }
        settings = Settings.model_validate(merge(settings.model_dump(), {"winch": extra}))
        daemon = Daemon(settings, simulators=SIMULATORS)
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), 30)
        frames = await Boat(daemon, port, task).cast()
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, 30) == 0
        await port.close()
    last = frames[-1].message
    assert isinstance(last, Finished) and last.depth_mm == 0
    [(outcome, reason, backend, _)] = _cast_rows(tmp_path)
    assert outcome == "aborted" and "stall: no drum pulse" in reason and backend == "gpio-mock"


def test_simulate_typed_as_a_command_is_answered_with_the_option(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["simulate"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'simulate'" in err
    assert err.rstrip().endswith("(did you mean: cc-daemon --simulate?)")


def test_a_start_that_cannot_drive_the_winch_leaves_no_journal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from importlib.util import find_spec

    if find_spec("lgpio") is not None:
        pytest.skip("lgpio is installed here: the daemon would open the GPIO chip")
    monkeypatch.chdir(tmp_path)
    for name in [n for n in __import__("os").environ if n.startswith("CC_DAEMON_")]:
        monkeypatch.delenv(name)
    with PtyPair(tmp_path / "tty") as pty:
        code = main(["--winch", "gpio", "--port", str(pty.path)])
    assert code == 1
    assert "the lgpio library is missing" in capsys.readouterr().err
    # `cc-daemon casts` must not find an empty journal of a run that never ran.
    assert list(tmp_path.glob("cc-daemon.db*")) == []
