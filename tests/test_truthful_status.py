"""Truthful leftovers (issue 29): the autopilot's times in the byte order the session
settled on, a depth estimate with its range in the status document, and a running
simulation found by `status` and `web` from its journal, as its header says."""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.status.view import status_lines
from cc_daemon.core.cast.timestamps import swap_bytes
from cc_daemon.core.protocol import DepthReport, Telemetry
from cc_daemon.core.status import DaemonStatus, Fix
from cc_daemon.core.winch.status import WinchStatus
from cc_daemon.daemon.status_report import StatusInputs, status_document
from cc_daemon.sim.console import describe_frame
from cc_daemon.sim.drum import DrumFaults
from tests.daemonkit import REPO
from tests.gpiokit import gpio_rig
from tests.waitkit import DEADLINE_S, until_sync


def _inputs(
    *, order: str = "big", settled: bool = False, winch: WinchStatus | None = None
) -> StatusInputs:
    fix = Telemetry(swap_bytes(26) if order == "little" else 26, -37260579, 404506308, 0, 4000, 90)
    snapshot = DaemonStatus(
        link_up=True, phase="stranded" if winch else "idle", probe_depth_m=0.244,
        planned_depth_m=2.64, cast_id=1, frames_in=5, frames_out=5, corrupt_frames=0,
        casts_completed=0, casts_aborted=0, casts_skipped=0, winch_fault="encoder dead",
        port_losses=0, last_fix=Fix(fix, 9.0, 1e9), winch=winch, fault_reports=3,
        timestamp_order=order, timestamp_order_settled=settled,
    )  # fmt: skip
    return StatusInputs(
        snapshot=snapshot, port="/dev/ttyAMA0", baudrate=9600, winch_backend="gpio",
        journal_health=None, monotonic=10.0, wall=1e9, uptime_s=17.0,
    )  # fmt: skip


def test_the_fix_gives_the_autopilots_time_in_the_settled_order() -> None:
    # The deployed firmware writes 26 s as 1A 00: read big-endian, 6656 (issue 29).
    settled = status_document(_inputs(order="little", settled=True))["fix"]
    assert settled["timestamp_s"] == 26
    assert settled["timestamp_order"] == "little" and settled["timestamp_order_settled"]
    manual = status_document(_inputs())["fix"]
    assert manual["timestamp_s"] == 26 and manual["timestamp_order"] == "big"


def test_the_live_view_reads_the_autopilots_frames_in_that_order_and_ours_as_sent() -> None:
    frame = Telemetry(swap_bytes(26), -37260579, 404506308, 0, 4000, 90)
    assert describe_frame(frame, "little").startswith("P-T t=26 ")
    assert describe_frame(frame).startswith("P-T t=6656 ")  # before the order is settled
    assert describe_frame(DepthReport(30, 1250), "little") == "R-M t=30 depth 1.250 m"


def test_an_estimated_depth_reaches_the_status_with_its_range() -> None:
    winch = WinchStatus(0.244, False, False, "encoder dead", None, 0.0, 2.686)
    doc = status_document(_inputs(winch=winch))
    assert doc["winch"]["depth_low_m"] == 0.0 and doc["winch"]["depth_high_m"] == 2.686
    reported = doc["cast"]["fault_reported"]
    assert reported["depth_m"] == 0.244 and reported["r_l_sent"] == 3
    assert (reported["depth_low_m"], reported["depth_high_m"]) == (0.0, 2.686)
    words = dict(status_lines(doc))  # what `cc-daemon status` prints
    assert words["STRANDED"].startswith("probe between 0.00 and 2.69 m (an estimate: best 0.24 m)")
    measured = status_document(_inputs(winch=WinchStatus(0.5, False, False, "jam")))
    assert dict(status_lines(measured))["STRANDED"].startswith("probe at 0.24 m (")
    assert measured["winch"]["depth_low_m"] is None
    assert measured["cast"]["fault_reported"]["depth_high_m"] is None


async def test_the_gpio_winch_says_where_the_probe_may_be_when_its_count_died() -> None:
    async with gpio_rig(adc=True, faults=DrumFaults(encoder_dead_in_from_m=1.0)) as rig:
        rig.winch.move_to(2.0)
        await rig.settle()
        assert rig.winch.status().depth_low_m is None  # counted: measured
        rig.winch.move_to(0.0)  # the encoder dies on the way up
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("encoder dead")
        assert status.depth_low_m is not None and status.depth_high_m is not None
        assert status.depth_low_m <= rig.drum.line_m <= status.depth_high_m
        assert status.depth_low_m <= status.depth_m <= status.depth_high_m


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
    return {**env, "PYTHONPATH": str(REPO)}


def _cc(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cc_daemon", *args],
        cwd=cwd,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=DEADLINE_S,
        check=False,
    )


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_status_and_web_find_a_running_simulation_as_its_header_says(tmp_path: Path) -> None:
    sim = subprocess.Popen(
        [sys.executable, "-m", "cc_daemon", "--simulate", "--plain", "--stations", "2"],
        cwd=tmp_path, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert sim.stdout is not None
        header = [sim.stdout.readline() for _ in range(4)]
        assert "watch it from another terminal:" in header[2], header
        assert header[2].rstrip().endswith("status --db simulate.db --watch"), header
        assert header[3].rstrip().endswith("web --db simulate.db"), header

        def settled() -> dict[str, Any] | None:
            asked = _cc(tmp_path, "status", "--db", "simulate.db", "--json")
            if asked.returncode != 0:
                return None
            doc: dict[str, Any] = json.loads(asked.stdout)
            fix = doc.get("fix") or {}
            return doc if fix.get("timestamp_order_settled") else None

        doc = until_sync(settled, "the daemon settling the byte order", DEADLINE_S, every=0.5)
        # The autopilot's clock started with the run: never ahead of the daemon's uptime.
        assert doc["fix"]["timestamp_order"] == "little"
        assert 0 <= doc["fix"]["timestamp_s"] <= doc["daemon"]["uptime_s"] + 2
        # Plain `status`, from where the simulation runs, finds it too.
        plain = _cc(tmp_path, "status")
        assert plain.returncode == 0, plain.stderr
        assert f"journal   {tmp_path / 'simulate.db'}" in plain.stdout
        rest, _ = sim.communicate(timeout=180)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.communicate()
    assert sim.returncode == 0, rest
    assert "web --db simulate.db   (the field page" in rest
    assert not list(tmp_path.glob("*.sock"))  # the run's sockets went with it
    # The journal knows the mission: the same count as the verdict, the same names.
    assert "1 of 1 castable station measured" in rest  # S2 is the shoal
    table = _cc(tmp_path, "surveys").stdout.splitlines()
    assert table[1].split()[3:6] == ["2", "1", "1"], table
    casts = _cc(tmp_path, "casts").stdout
    assert casts.splitlines()[1].split()[1] == "S1" and casts.splitlines()[2].split()[1] == "S2"


def test_web_asks_the_socket_of_the_daemon_writing_its_db(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from cc_daemon.cli.status.command import socket_candidates
    from cc_daemon.config.statuspaths import hand_socket_path

    for name in [k for k in os.environ if k.startswith("CC_DAEMON_")]:
        monkeypatch.delenv(name)
    config = tmp_path / "empty.toml"
    config.write_text("")
    db = tmp_path / "bench.db"
    assert socket_candidates(None, config, db)[0] == hand_socket_path(db)
    # With no journal named anywhere, the simulator's ./simulate.db comes before the
    # service's socket.
    monkeypatch.chdir(tmp_path)
    paths = socket_candidates(None, config, None)
    assert hand_socket_path(tmp_path / "simulate.db") in paths
    assert str(paths[-1]) == "/run/cc-daemon/status.sock"


def test_make_simulate_says_the_simulators_own_exit_status(tmp_path: Path) -> None:
    make = shutil.which("make")
    if make is None:
        pytest.skip("make is not installed")
    # A stand-in for the venv's programs: the simulator ends SURVEY INCOMPLETE (3).
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, body in (("python", "exit 0"), ("cc-daemon", 'echo "ran $*"; exit 3')):
        (bin_dir / name).write_text(f"#!/bin/sh\n{body}\n")
        (bin_dir / name).chmod(0o755)
    stamp = tmp_path / "stamp"
    stamp.touch()
    made = subprocess.run(
        [make, "-s", "-C", str(REPO), "simulate", f"BIN={bin_dir}", f"EXTRAS_STAMP={stamp}",
         "ARGS=--winch-stall"],
        capture_output=True, text=True, timeout=DEADLINE_S, check=False,
    )  # fmt: skip
    assert "ran --simulate --winch-stall" in made.stdout
    assert made.returncode == 2  # make's own, for any failure
    assert "make: the simulator exited 3 (docs/simulator.md, Exit status)" in made.stderr


async def test_the_daemon_says_its_settled_order_and_that_mock_pins_move_no_probe(
    tmp_path: Path,
) -> None:
    from tests.test_gpio_daemon import _boat

    async with gpio_rig() as rig, _boat(tmp_path, rig) as boat:
        # The deployed firmware's T frames about 1.1 s apart, its whole-second clock
        # written little-endian, until the daemon has learnt the order (on a busy
        # machine a pair too far apart says nothing: the next ones will).
        started, sent = time.monotonic(), 0
        deadline = started + DEADLINE_S
        while not boat.daemon.snapshot().timestamp_order_settled:
            assert time.monotonic() < deadline, "the byte order never settled"
            sent = 40 + int(time.monotonic() - started)
            await boat.port.send(Telemetry(swap_bytes(sent), -37260579, 404506308, 0, 4000, 90))
            await asyncio.sleep(1.1)  # the firmware's frame period
        doc = status_document(boat.daemon.status_inputs())
    assert doc["fix"]["timestamp_order"] == "little" and doc["fix"]["timestamp_order_settled"]
    assert doc["fix"]["timestamp_s"] == sent
    assert doc["daemon"]["simulated"] is True and doc["winch"]["backend"] == "gpio-mock"
