"""End to end: the daemon as a subprocess against `simulate-autopilot` on a
null-modem pair of ptys, as the deployed 2023 firmware and as the manual."""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import sqlite3
from collections.abc import Callable
from pathlib import Path

import pytest

from cc_daemon.sim.options import AutopilotOnlyOptions
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.runner import run_autopilot
from tests.daemonkit import START_S, DaemonProcess

pytestmark = pytest.mark.slow
MakeDaemon = Callable[..., DaemonProcess]


@pytest.mark.parametrize("firmware", ["ucm-2023", "manual"])
async def test_a_survey_against_each_firmware_profile(
    tmp_path: Path, make_daemon: MakeDaemon, firmware: str
) -> None:
    with PtyPair(tmp_path / "ttyPI") as pi_end, PtyPair(tmp_path / "ttyLAPTOP") as laptop_end:
        loop = asyncio.get_running_loop()

        def relay(src: int, dst: int) -> None:
            with contextlib.suppress(BlockingIOError, OSError):
                os.write(dst, os.read(src, 4096))

        loop.add_reader(pi_end.master_fd, relay, pi_end.master_fd, laptop_end.master_fd)
        loop.add_reader(laptop_end.master_fd, relay, laptop_end.master_fd, pi_end.master_fd)
        daemon = make_daemon(
            {"serial": {"port": str(pi_end.path)}, "winch": {"sim": {"speed_m_s": 2.0}}}
        )
        try:
            daemon.start()
            # The autopilot judges an M unanswered after 1 s: start it once the daemon
            # listens (its start took 25 s on a loaded machine).
            await daemon.logged("serial port open", START_S)
            daemon.check_alive()
            out = io.StringIO()
            code = await run_autopilot(
                AutopilotOnlyOptions(
                    port=str(laptop_end.path),
                    stations=2,
                    frame_period_s=0.3 if firmware == "manual" else 1.1,  # 1.1: as it is
                    boat_speed_m_s=300.0,
                    firmware=firmware,  # type: ignore[arg-type]
                    out=out,
                    live=False,
                    handle_signals=False,
                )
            )
        finally:
            loop.remove_reader(pi_end.master_fd)
            loop.remove_reader(laptop_end.master_fd)
        daemon.send_signal()
        assert await daemon.wait_exit() == 0
    text = out.getvalue()
    assert code == 0, text + daemon.log_text()[-3000:]
    assert "protocol violations: 0" in text
    assert "corrupt frames: 0 from the daemon" in text
    assert not [e for e in daemon.log_events() if e.get("event") == "corrupt frame"]
    with sqlite3.connect(daemon.db) as db:
        outcomes = db.execute("SELECT outcome FROM casts ORDER BY id").fetchall()
        jogs = db.execute("SELECT detail_json FROM events WHERE kind = 'jog_stopped'").fetchall()
        modes = db.execute("SELECT DISTINCT measuring_mode FROM fixes WHERE frame = 'P-M'")
        orders = db.execute("SELECT ap_time_order FROM fixes ORDER BY id DESC LIMIT 1")
        mode_values, last_order = modes.fetchall(), orders.fetchone()
    assert sorted(o for (o,) in outcomes) == ["completed", "skipped-shallow"]
    if firmware == "ucm-2023":
        assert mode_values == [(0,)]  # the 26-byte M, read whole
        assert last_order == ("little",)  # detected from the T frames
        assert len(jogs) == 2 and "stick jog before the station" in text
    else:
        assert mode_values == [(None,)] and jogs == []
        assert last_order == ("big",)
