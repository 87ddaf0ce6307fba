"""The daemon with a sonde: real pymodbus client and server over ptys, a real journal.

The cast never waits for the sonde: an adapter pulled out mid-cast leaves the
cast running, its readings recorded as missing with the reason, and the link
comes back by itself. A probe on the bottom stops the descent.
"""

from __future__ import annotations

import asyncio
import random
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import structlog

from cc_daemon.config import Settings
from cc_daemon.core.protocol import Ack, DepthReport, Finished
from cc_daemon.daemon.service import EXIT_OK, Daemon
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.sonde import SimulatedSonde
from cc_daemon.sim.water import SondeModel, WaterColumn
from cc_daemon.store import JournalReader
from tests.daemonkit import FAST_CAST, merge, station

PERIOD_S = 0.5

FAST_SONDE = {
    "backend": "modbus",
    "period_s": PERIOD_S,
    "idle_period_s": 1.0,
    # Far above a reply's few milliseconds, even on a loaded machine.
    "timeout_s": 0.8 * PERIOD_S,
    "retries": 0,
    "reconnect_initial_s": 0.1,
    "reconnect_max_s": 0.3,
}


class Rig:
    def __init__(self, tmp_path: Path, config: dict[str, Any], model: SondeModel) -> None:
        self.tmp = tmp_path
        self.pty = PtyPair(tmp_path / "tty")
        self.db = tmp_path / "j.db"
        sonde_path = tmp_path / "ttySONDE"
        base = merge(FAST_CAST, {"serial": {"port": str(self.pty.path)}})
        base = merge(base, {"store": {"path": str(self.db)}, "sonde": FAST_SONDE})
        base = merge(base, {"sonde": {"port": str(sonde_path)}})
        # Casts at the winch's own speed (the profile's limit: tests/test_cast_resolution.py).
        base = merge(base, {"profile": {"bin_m": 5.0, "min_count": 1, "resolve": []}})
        self.settings = Settings.model_validate(merge(base, config))
        self.daemon = Daemon(self.settings)
        self.sonde = SimulatedSonde(sonde_path, line_out=self._line_out, model=model)

    def _line_out(self) -> float:
        winch = self.daemon._winch
        return winch.status().depth_m if winch is not None else 0.0

    def statuses(self) -> list[str]:
        """The cast's sonde rows journaled so far (the writer commits each second)."""
        if not self.db.exists():
            return []
        with JournalReader(self.db) as reader:
            return [r.status for r in reader.sonde_samples() if r.cast_id is not None]

    async def until(self, condition: Any, timeout: float = 60.0) -> None:
        async with asyncio.timeout(timeout):
            while not condition():  # noqa: ASYNC110 - the daemon's writer thread makes it so
                await asyncio.sleep(0.1)

    async def finished(self, port: FramePort, timeout: float) -> list[Any]:
        messages = []
        deadline = asyncio.get_running_loop().time() + timeout
        while asyncio.get_running_loop().time() < deadline:
            got = await port.receive(0.5)
            if got is None:
                continue
            messages.append(got.message)
            if isinstance(got.message, Finished):
                break
        return messages


@pytest.fixture
async def make_rig(tmp_path: Path) -> AsyncIterator[Any]:
    made: list[tuple[Rig, FramePort]] = []

    async def factory(config: dict[str, Any], model: SondeModel) -> tuple[Rig, FramePort]:
        rig = Rig(tmp_path, config, model)
        rig.sonde.start()
        port = await FramePort.over_fd(rig.pty.master_fd)
        made.append((rig, port))
        return rig, port

    yield factory
    for rig, port in made:
        await port.close()
        rig.sonde.stop()
        rig.pty.close()


async def test_unplugged_sonde_during_a_cast(make_rig: Any) -> None:
    rig, port = await make_rig({"cast": {"bottom_dwell_s": 3.0}}, SondeModel())
    task = asyncio.create_task(rig.daemon.run())
    await asyncio.wait_for(rig.daemon.ready.wait(), 30)
    await port.send(station())
    assert (await port.receive(30)).message == Ack(100)  # type: ignore[union-attr]
    await rig.until(lambda: "ok" in rig.statuses())  # read while the cast runs
    rig.sonde.unplug()
    await rig.until(lambda: rig.statuses().count("disconnected") >= 3)
    rig.sonde.replug()
    messages = await rig.finished(port, 60)
    rig.daemon.request_shutdown()
    assert await asyncio.wait_for(task, 30) == EXIT_OK
    assert isinstance(messages[-1], Finished)  # the cast went on and ended normally
    assert sum(isinstance(m, DepthReport) for m in messages) >= 5
    with JournalReader(rig.db) as reader:
        (cast,) = reader.casts()
        rows = reader.sonde_samples(cast_id=cast.id)
        events = [e.kind for e in reader.events()]
    assert cast.outcome == "completed"
    statuses = [r.status for r in rows]
    first_gap = statuses.index("disconnected")
    assert "ok" in statuses[:first_gap] and "ok" in statuses[first_gap:]
    lost = [r for r in rows if r.status == "disconnected"]
    assert len(lost) >= 3
    assert all(set(r.values.values()) == {None} for r in lost)  # missing, never 0.0
    assert all(set(r.missing.values()) == {"disconnected"} for r in lost)
    assert all(r.sonde_depth_m is None and r.line_out_m is not None for r in lost)
    ok = [r for r in rows if r.status == "ok"]
    assert all(r.values["temperature"] is not None for r in ok)
    assert {r.phase for r in rows} >= {"descending", "ascending"}
    assert events.count("sonde_port_opened") >= 2 and "sonde_port_lost" in events
    # The beat: readings of the cast on a PERIOD_S beat, missed beats skipped, never a
    # burst to catch up (a beat read late on a loaded machine may sit closer to the next:
    # the count says whether beats were added). A `late` row is a reply that came after
    # its request's time-out, stamped with the time it was asked (issue 20): it sits
    # beside that request's own row, off the beat.
    beat = [r for r in rows if r.status != "late"]
    assert len(beat) <= (beat[-1].mono_s - beat[0].mono_s) / PERIOD_S + 1


async def test_bottom_contact_stops_the_descent(make_rig: Any) -> None:
    model = SondeModel(WaterColumn(bottom_m=1.5), slant_deg=0.0, rng=random.Random(3))
    config = {
        # No sonar bottom: a blind cast, allowed as deep as the target here.
        "cast": {"target_depth_m": 6.0, "depth_source": "sonde", "blind_max_depth_m": 6.0},
        "winch": {"sim": {"speed_m_s": 0.5}},
        # Blind, at the approach speed (0.25 m/s): ~0.25 m of line runs on past the bed.
        "sonde": {"bottom_contact_s": 1.0, "depth_disagreement_m": 0.2},
    }
    rig, port = await make_rig(config, model)
    task = asyncio.create_task(rig.daemon.run())
    await asyncio.wait_for(rig.daemon.ready.wait(), 30)
    await port.send(station(confidence=0))  # no sonar bottom: the sonde is the only guard
    messages = await rig.finished(port, 90)
    rig.daemon.request_shutdown()
    assert await asyncio.wait_for(task, 30) == EXIT_OK
    assert isinstance(messages[-1], Finished)
    with JournalReader(rig.db) as reader:
        (cast,) = reader.casts()
        events = {e.kind: e.detail for e in reader.events()}
    assert cast.outcome == "completed"
    # Stopped about bottom_contact_s after touching, far above the 6 m target.
    assert cast.reached_depth_m is not None and 1.5 < cast.reached_depth_m < 4.0
    assert events["bottom_contact"]["sonde_depth_m"] == pytest.approx(1.5, abs=0.05)
    assert "sonde_depth_disagreement" in events
    # depth_source = "sonde": R-M says where the probe is, not how much line is out.
    reported = [m.depth_mm for m in messages if isinstance(m, DepthReport)]
    assert max(reported) <= 1600


async def test_a_cast_with_a_sonde_descends_no_faster_than_its_profile_resolves(
    make_rig: Any,
) -> None:
    # 1.5 m bins, temperature's 2 s: 0.75 m/s, under the winch's 1 m/s (issue 28).
    config = {"profile": {"bin_m": 1.5, "min_count": 1, "resolve": ["temperature"]}}
    rig, port = await make_rig(config, SondeModel())
    with structlog.testing.capture_logs() as logs:
        task = asyncio.create_task(rig.daemon.run())
        await asyncio.wait_for(rig.daemon.ready.wait(), 30)
    said = [e["event"] for e in logs if e["event"].startswith("profile resolution")]
    assert said == [
        "profile resolution: continuous casts descend at 0.75 m/s (limit 0.75 m/s from 1.5 m "
        "bins, temperature 2 s, >= 1 readings a bin; winch 1 m/s): 4.0 readings a bin; lags "
        "at that speed: temperature 1.50 m, ph 3.00 m, do_saturation 6.00 m, "
        "do_concentration 6.00 m"
    ]
    await port.send(station())
    messages = await rig.finished(port, 90)
    rig.daemon.request_shutdown()
    assert await asyncio.wait_for(task, 30) == EXIT_OK
    assert isinstance(messages[-1], Finished)
    with JournalReader(rig.db) as reader:
        (cast,) = reader.casts()
        down = [s for s in reader.samples(cast_id=cast.id) if s.phase == "descending"]
    assert cast.plan["profile"]["descent_limit_m_s"] == 0.75
    assert cast.plan["legs"][0]["max_speed_m_s"] == 0.75
    moving = [s for s in down if 0.0 < s.depth_m < 3.0]
    assert len(moving) >= 2
    speed = (moving[-1].depth_m - moving[0].depth_m) / (moving[-1].mono_s - moving[0].mono_s)
    assert speed == pytest.approx(0.75, rel=0.05)  # the winch alone runs 1 m/s
