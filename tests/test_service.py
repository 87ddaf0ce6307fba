"""The service in-process, for paths a subprocess cannot reach: a bug in the
cast machine itself, and shutdown details."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import structlog

from cc_daemon.cast.machine import CastMachine
from cc_daemon.config import Settings
from cc_daemon.protocol import Ack, DepthReport, Finished, ProbePositionRequest
from cc_daemon.service import EXIT_OK, EXIT_PROBE_MAY_BE_DOWN, Daemon
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import FAST_CAST, merge, station


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
        await asyncio.wait_for(daemon.ready.wait(), 5)
        await port.send(station())
        assert (await port.receive(1)).message == Ack(100)  # type: ignore[union-attr]
        received = [await port.receive(1.5) for _ in range(4)]
        status = daemon.snapshot()
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, 5) == EXIT_PROBE_MAY_BE_DOWN
    messages = [r.message for r in received if r is not None]
    assert len(messages) == 4
    assert all(isinstance(m, DepthReport) for m in messages)  # still reporting, never R-F
    assert not any(isinstance(r.message, Finished) for r in port.received)
    assert status.phase != "idle"
    assert daemon._winch is not None and not daemon._winch.status().moving  # motor stopped
    criticals = [e for e in logs if e["log_level"] == "critical"]
    assert any("internal error" in e["event"] for e in criticals)
    assert sum("PROBE STATE UNKNOWN" in e["event"] for e in criticals) >= 2


async def test_a_second_ctrl_c_while_idle_is_a_clean_exit(rig: tuple[Daemon, FramePort]) -> None:
    daemon, port = rig
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), 5)
    await port.send(ProbePositionRequest(9))
    assert await port.receive(1) is not None
    daemon.request_shutdown()
    daemon.request_shutdown(immediate=True)
    assert await asyncio.wait_for(task, 5) == EXIT_OK


async def test_no_cast_starts_once_shutting_down(rig: tuple[Daemon, FramePort]) -> None:
    daemon, port = rig
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), 5)
    daemon._shutting_down = True  # as request_shutdown does, before the loop winds down
    await port.send(station())
    assert await port.receive(0.5) is None  # no R-O: the autopilot must not count on us
    daemon.request_shutdown()
    assert await asyncio.wait_for(task, 5) == EXIT_OK
    assert daemon.snapshot().casts_completed == 0
