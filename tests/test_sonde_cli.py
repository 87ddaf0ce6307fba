"""`cc-daemon simulate-sonde` as a real subprocess, read by the real reader."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from cc_daemon.config.sonde import SondeSettings
from cc_daemon.drivers.sonde.reader import OK, SondeReader

REPO = Path(__file__).resolve().parent.parent


async def test_simulate_sonde_serves_the_default_map(tmp_path: Path) -> None:
    port = tmp_path / "ttySONDE"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = await asyncio.create_subprocess_exec(
        *[sys.executable, "-m", "cc_daemon", "simulate-sonde", "--port", str(port), "--depth", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    try:
        assert proc.stdout is not None
        line = await asyncio.wait_for(proc.stdout.readline(), 20)
        assert b"simulated sonde on" in line
        reader = SondeReader(SondeSettings(backend="modbus", port=str(port)))
        reading = await reader.read()
        await reader.close()
        assert reading.status == OK
        assert reading.values["depth"] == pytest.approx(1.98, abs=0.05)  # 2 m of slanted line
        assert 20.0 < (reading.values["temperature"] or 0) < 25.0  # above the thermocline
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = await asyncio.wait_for(proc.communicate(), 10)
    assert proc.returncode == 0, err
    assert b"served 1 requests" in out


def test_bad_fault_rate_is_usage_error(tmp_path: Path) -> None:
    from cc_daemon.cli.app import main

    assert main(["simulate-sonde", "--port", str(tmp_path / "t"), "--fault-rate", "2"]) == 2
