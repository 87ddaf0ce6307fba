"""The daemon in-process on a real pty against the deployed firmware's ways:
its 26-byte M, little-endian timestamps, the RC stick, R-F repeats, a lost M."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import sqlite3
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any, NamedTuple

import pytest
import structlog

from cc_daemon.config import Settings
from cc_daemon.core.cast.timestamps import swap_bytes
from cc_daemon.core.protocol import (
    Ack,
    DepthReport,
    Finished,
    Message,
    ProbeDown,
    ProbePosition,
    ProbePositionRequest,
    ProbeUp,
    Telemetry,
    encode,
)
from cc_daemon.core.winch.physics import LinePhysics
from cc_daemon.daemon.service import EXIT_OK, Daemon
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.drivers.winch.simulated import SimulatedWinch
from cc_daemon.ground.clock import SystemClock
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import (
    FAST_CAST,
    WAIT_S,
    frames_before_reply,
    merge,
    next_frame,
    station,
)
from tests.test_firmware_frames import M_26
from tests.waitkit import until


class Rig(NamedTuple):
    daemon: Daemon
    port: FramePort
    winch: SimulatedWinch
    db: Path
    stop: Callable[[], Awaitable[None]]  # shut the daemon down and wait: the journal is closed


def events(db: Path, kind: str) -> list[dict[str, Any]]:
    with sqlite3.connect(db) as conn:
        rows = conn.execute("SELECT detail_json FROM events WHERE kind = ? ORDER BY id", (kind,))
        return [json.loads(row[0]) for row in rows.fetchall()]


async def until_finished(port: FramePort, timeout: float = WAIT_S) -> list[Message]:
    out: list[Message] = []
    while (got := await port.receive(timeout)) is not None:
        out.append(got.message)
        if isinstance(got.message, Finished):
            return out
    raise AssertionError(f"no R-F: {out}")


@pytest.fixture
async def rig(tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[Rig]:
    extra = getattr(request, "param", {})
    with PtyPair(tmp_path / "tty") as pty:
        config = merge(
            FAST_CAST,
            {"serial": {"port": str(pty.path)}, "store": {"path": str(tmp_path / "j.db")}},
        )
        winch = SimulatedWinch(LinePhysics(speed_m_s=1.0, max_line_m=20.0), SystemClock())
        daemon = Daemon(Settings.model_validate(merge(config, extra)), winch=winch)
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)

        async def stop() -> None:
            daemon.request_shutdown()
            assert await asyncio.wait_for(asyncio.shield(task), WAIT_S) == EXIT_OK

        try:
            yield Rig(daemon, port, winch, tmp_path / "j.db", stop)
        finally:
            await stop()
            await port.close()


async def test_the_firmwares_26_byte_m_runs_a_whole_cast(rig: Rig) -> None:
    daemon, port, _, db, stop = rig
    await port.send(M_26)
    frames = await until_finished(port)
    assert isinstance(frames[0], Ack) and any(isinstance(f, DepthReport) for f in frames)
    assert daemon.snapshot().casts_completed == 1 and daemon.snapshot().corrupt_frames == 0
    await stop()
    with sqlite3.connect(db) as conn:
        assert conn.execute("SELECT frame, measuring_mode FROM fixes").fetchall() == [("P-M", 0)]


# Ten repeats allowed: the P-S, not the count, must be what stops them.
@pytest.mark.parametrize(
    "rig", [{"cast": {"rf_repeat_after_s": 0.5, "rf_repeats": 10}}], indirect=True
)
async def test_rf_is_repeated_after_silence_and_a_frame_stops_it(rig: Rig) -> None:
    daemon, port, _, db, stop = rig
    await port.send(station(sonar_mm=500))  # too shallow: skipped, R-F at once
    first = await until_finished(port)
    again = [(await next_frame(port)).message for _ in range(2)]  # 0.5 s of silence, twice
    assert again == [first[-1], first[-1]]  # the same R-F, byte for byte
    # The autopilot speaks: it read one. What the daemon sent before it heard the S
    # (a third repeat, on a slow machine) comes before the R-P; nothing after it.
    before = await frames_before_reply(port)
    assert all(m == first[-1] for m in before), before
    assert daemon._line.rf.next_deadline() is None  # no repeat is due, ever
    await stop()
    repeats = [e["repeat"] for e in events(db, "rf_repeated")]
    assert repeats == list(range(1, 3 + len(before)))


async def hold_stick(
    port: FramePort, stick: type[ProbeDown | ProbeUp], done: Callable[[], bool]
) -> None:
    """The stick held (a frame every 0.25 s, as the RC link repeats it) until `done()`."""
    frames = 0
    while not done():
        assert frames < WAIT_S / 0.25, f"{stick.__name__} held for {WAIT_S} s"
        await port.send(stick(frames))
        frames += 1
        await asyncio.sleep(0.25)


# The dead-man's hold is eight times the stick's repeat: a frame late on a busy
# machine is no release.
@pytest.mark.parametrize("rig", [{"serial": {"jog_hold_s": 2.0}}], indirect=True)
async def test_the_stick_jogs_the_probe_down_then_up_with_no_reply(rig: Rig) -> None:
    daemon, port, winch, db, stop = rig
    await hold_stick(port, ProbeDown, lambda: winch.status().depth_m >= 2.0)
    assert daemon.snapshot().jog == "down"
    released_at_m = winch.status().depth_m
    await until(lambda: daemon.snapshot().jog is None, what="the dead-man stop")
    status = winch.status()  # released: stopped by the dead-man, further down
    assert not status.moving and released_at_m < status.depth_m < 20.0
    await hold_stick(port, ProbeUp, lambda: winch.status().at_home)  # hauled all in
    await until(lambda: daemon.snapshot().jog is None, what="the jog's end at home")
    assert await frames_before_reply(port) == []  # no reply to a stick frame, ever
    assert daemon.snapshot().casts_completed == 0
    await stop()
    stops = events(db, "jog_stopped")
    assert [(e["stick"], e["reason"]) for e in stops] == [
        ("down", "stick released"),
        ("up", "probe home"),
    ]
    assert stops[0]["depth_m"] == pytest.approx(status.depth_m, abs=0.2)
    assert [e["stick"] for e in events(db, "jog_started")] == ["down", "up"]


async def test_u_during_a_cast_aborts_it_and_d_is_ignored(rig: Rig) -> None:
    _, port, winch, db, stop = rig
    await port.send(station())
    await next_frame(port, Ack)
    await until(lambda: winch.status().depth_m > 0.5, what="the probe on its way down")
    with structlog.testing.capture_logs() as logs:
        await port.send(ProbeDown(3))
        await until(lambda: any("probe-down stick ignored" in e["event"] for e in logs))
    await port.send(ProbeUp(4))
    frames = await until_finished(port)
    assert isinstance(frames[-1], Finished) and frames[-1].depth_mm == 0
    assert winch.status().at_home
    await stop()
    with sqlite3.connect(db) as conn:
        [(outcome, reason)] = conn.execute("SELECT outcome, reason FROM casts").fetchall()
    assert outcome == "aborted" and "probe up (RC stick)" in reason
    assert events(db, "jog_started") == []  # a U in a cast is no jog


@pytest.mark.parametrize("rig", [{"serial": {"jog_hold_s": 5.0}}], indirect=True)
async def test_a_station_while_jogged_down_brings_the_probe_home_first(rig: Rig) -> None:
    _, port, winch, db, stop = rig
    await port.send(ProbeDown(1))
    await until(lambda: winch.status().depth_m > 0.5, what="the jog paying out")
    await port.send(station())
    frames = await until_finished(port)
    assert isinstance(frames[0], Ack) and frames[-1] == Finished(frames[-1].timestamp_s, 0)
    assert winch.status().at_home
    await stop()
    assert [e["reason"] for e in events(db, "jog_stopped")] == ["start-measuring"]
    with sqlite3.connect(db) as conn:
        [(reason,)] = conn.execute("SELECT reason FROM casts").fetchall()
    assert "down with no cast" in reason


async def test_little_endian_timestamps_are_detected_and_echoed_in_their_real_value(
    rig: Rig,
) -> None:
    _, port, _, db, stop = rig
    fields = (-37234000, 404508000, 650000, 30_000, 100)
    with structlog.testing.capture_logs() as logs:

        def decided() -> list[dict[str, Any]]:
            return [e for e in logs if e["event"] == "autopilot timestamp byte order decided"]

        # About 1 s apart, little-endian as the firmware writes them, until the daemon
        # has decided (three pairs that agree; a pair a busy machine reads too close
        # together or too far apart says nothing, and the firmware simply goes on).
        t = 300
        while not decided():
            assert t < 330, "no decision after 30 T frames"
            await port.send(Telemetry(swap_bytes(t), *fields))
            t += 1
            await asyncio.sleep(1.0)
        await port.send(ProbePositionRequest(swap_bytes(t)))
        reply = (await next_frame(port, ProbePosition)).message
    assert reply == ProbePosition(t, 0)  # big-endian, in the autopilot's real clock
    [decision] = decided()
    assert decision["order"] == "little" and len(decision["evidence"]) == 3
    await stop()
    with sqlite3.connect(db) as conn:
        rows = conn.execute("SELECT ap_time_s, ap_time_order FROM fixes ORDER BY id").fetchall()
    assert rows[0] == (swap_bytes(300), "big")  # before deciding: the manual's order
    assert rows[-1] == (t - 1, "little")


def _flipped(frame: bytes, at: int) -> bytes:
    broken = bytearray(frame)
    broken[at] ^= 0x01
    return bytes(broken)


# An M mangled so that no frame can start in it (no sync byte left): the parser
# discards its bytes and reports no corrupt frame; they are the same evidence.
UNFRAMED = bytes(b for b in M_26 if b not in (0x50, 0x52))


@pytest.mark.parametrize(
    "broken", [_flipped(M_26, 12), UNFRAMED], ids=["a-corrupt-frame", "bytes-no-frame-holds"]
)
async def test_telemetry_stopping_after_corrupt_frames_is_a_lost_m(rig: Rig, broken: bytes) -> None:
    daemon, port, _, db, stop = rig
    await port.send(Telemetry(1, -37234000, 404508000, 650000, 30_000, 100))
    await port.send(bytes(broken))
    lost = await until(lambda: daemon.snapshot().lost_start, what="a lost M suspected")
    assert "start-measuring frame may have been lost" in lost
    assert port.received == []  # nothing sent: we cannot answer it
    await port.send(Telemetry(5, -37234000, 404508000, 650000, 30_000, 100))
    # The S after the T is answered, so the T was heard; still nothing for the M.
    assert await frames_before_reply(port) == []
    assert daemon.snapshot().lost_start is None
    await stop()
    [lost] = events(db, "start_measuring_lost")
    assert lost["corrupt_frames"] >= 1


async def test_a_corrupt_frame_then_a_good_fix_in_one_read_is_no_lost_m(rig: Rig) -> None:
    # The line works (a fix came after the corrupt frame): silence after it is no
    # evidence of a lost M. The rest of the corrupt frame, which the parser reads
    # through as it resynchronises, once counted again at the read's end as bytes
    # no frame holds, after the fix: a false alarm after 3.5 s (a review found it).
    daemon, port, _, db, stop = rig
    good = encode(Telemetry(1, -37234000, 404508000, 650000, 30_000, 100))
    await port.send(good)
    await until(lambda: daemon.frames_in == 1, what="the first fix heard")
    await port.send(_flipped(good, 24) + encode(Telemetry(2, -37234000, 404508000, 650000, 0, 0)))
    await until(lambda: daemon.frames_in == 2, what="the second fix heard")
    assert daemon.snapshot().corrupt_frames >= 1
    # Nothing left to suspect: no silence is being timed (the false alarm came from
    # a corrupt frame counted after the fix, which set this deadline 3 s ahead).
    assert daemon._line.lost.next_deadline(cast_running=False) is None
    assert daemon.snapshot().lost_start is None
    await stop()
    assert events(db, "start_measuring_lost") == []


async def test_a_lost_m_shows_in_the_systemd_status_line(tmp_path: Path) -> None:
    sock_path = tmp_path / "notify.sock"
    with (
        socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server,
        PtyPair(tmp_path / "tty") as pty,
    ):
        server.bind(str(sock_path))
        server.setblocking(False)
        config = merge(
            FAST_CAST,
            {"serial": {"port": str(pty.path)}, "store": {"path": str(tmp_path / "j.db")}},
        )
        daemon = Daemon(Settings.model_validate(config), notifier=SystemdNotifier(str(sock_path)))
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
        await port.send(Telemetry(1, -37234000, 404508000, 650000, 30_000, 100))
        await port.send(M_26[:12] + b"\x00" + M_26[13:])  # a spoilt M
        await until(lambda: daemon.snapshot().lost_start, what="a lost M suspected")
        await port.send(Telemetry(6, -37234000, 404508000, 650000, 30_000, 100))
        await until(lambda: daemon.snapshot().lost_start is None, what="the T heard")
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, WAIT_S) == EXIT_OK
        await port.close()
        said = []
        with contextlib.suppress(BlockingIOError):
            while True:
                said.append(server.recv(1024).decode())
    statuses = [line for msg in said for line in msg.split("\n") if line.startswith("STATUS=")]
    lost = [s for s in statuses if "start-measuring frame may have been lost" in s]
    assert len(lost) == 1
    # (Each line may carry the simulated winch's prefix: FAST_CAST runs the sim winch.)
    again = [i for i, s in enumerate(statuses) if s.endswith("frames from the autopilot again")]
    assert again and statuses.index(lost[0]) < again[0]
