"""The daemon as a real subprocess on a pty pair, driven by a test autopilot.

Every test speaks real frames over a real pseudo-terminal to `python -m
cc_daemon`, and checks what came back (and, where it matters, the journal
file and the exit status).
"""

from __future__ import annotations

import asyncio
import itertools
import signal
import sqlite3
import time
from collections.abc import Callable

import pytest

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
from cc_daemon.sim.port import FramePort, Received
from tests.daemonkit import DaemonProcess, station

pytestmark = pytest.mark.slow
MakeDaemon = Callable[..., DaemonProcess]


def kinds(received: list[Received]) -> list[str]:
    return [r.message.frame for r in received]


async def run_cast(daemon: DaemonProcess, timeout: float = 20.0) -> list[Received]:
    """Collect everything up to and including the R-F."""
    assert daemon.port is not None
    out: list[Received] = []
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        got = await daemon.port.receive(left)
        if got is None:
            break
        out.append(got)
        if isinstance(got.message, Finished):
            return out
    raise AssertionError(f"no R-F; got {kinds(out)}\n{daemon.log_text()[-3000:]}")


def cast_rows(daemon: DaemonProcess) -> list[tuple[object, ...]]:
    with sqlite3.connect(daemon.db) as db:
        return db.execute("SELECT id, outcome FROM casts ORDER BY id").fetchall()


async def test_a_whole_cast(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    await port.send(Telemetry(99, -37260579, 404506308, 702385, 30_000, 100))
    sent_at = time.monotonic()
    await port.send(station())
    frames = await run_cast(daemon)
    assert frames[0].message == Ack(frames[0].message.timestamp_s)
    assert frames[0].time - sent_at < 0.5
    reports = [r for r in frames if isinstance(r.message, DepthReport)]
    depths = [r.message.depth_mm for r in reports]
    assert 5 <= len(reports) <= 9  # about one a second for a ~7 s cast
    deepest = depths.index(max(depths))
    assert max(depths) == 3000
    assert depths[:deepest] == sorted(depths[:deepest])
    assert depths[deepest:] == sorted(depths[deepest:], reverse=True)
    gaps = [b.time - a.time for a, b in itertools.pairwise(reports)]
    assert all(0.75 < gap < 1.25 for gap in gaps), gaps  # tolerant of a loaded CI machine
    finished = frames[-1].message
    assert isinstance(finished, Finished) and finished.depth_mm == 0
    # Timestamps follow the autopilot's clock (M carried t=100).
    assert frames[0].message.timestamp_s == 100
    assert reports[0].message.timestamp_s == 101
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    assert cast_rows(daemon) == [(1, "completed")]
    # The journal holds the whole profile: what went over the link, plus the
    # probe at the surface when R-O and R-F went out.
    with sqlite3.connect(daemon.db) as db:
        samples = db.execute(
            "SELECT depth_m, phase FROM samples WHERE cast_id = 1 ORDER BY id"
        ).fetchall()
    assert [round(d * 1000) for d, _ in samples[1:-1]] == depths
    assert samples[0] == (0.0, "descending")
    assert samples[-1] == (0.0, "ascending")


async def test_the_bottom_limits_the_cast(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    await daemon.start_and_connect()
    assert daemon.port is not None
    await daemon.port.send(station(sonar_mm=2000, confidence=90))
    frames = await run_cast(daemon)
    depths = [r.message.depth_mm for r in frames if isinstance(r.message, DepthReport)]
    assert max(depths) == 1500  # 2.0 m of water, 0.5 m clearance


async def test_a_too_shallow_station_is_skipped_at_once(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    await port.send(station(sonar_mm=600, confidence=95))
    frames = await daemon.collect(1.5)
    assert kinds(frames) == ["R-O", "R-F"]
    assert frames[1].message == Finished(frames[1].message.timestamp_s, 0)
    assert any(e.get("event") == "cast skipped: station too shallow" for e in daemon.log_events())


async def test_s_during_a_cast_gets_the_current_depth(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack, 2)
    await asyncio.sleep(2.5)  # the probe is about 2.5 m down
    asked = time.monotonic()
    await port.send(ProbePositionRequest(500))
    reply = await daemon.expect(ProbePosition, 1)
    assert reply is not None
    assert reply.time - asked < 0.5
    assert 2000 <= reply.message.depth_mm <= 3000
    assert reply.message.timestamp_s == 500


async def test_m_resent_every_half_second_makes_exactly_one_cast(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    received: list[Received] = []

    async def resend_m(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            await port.send(station())
            await asyncio.sleep(0.5)

    sender = asyncio.create_task(resend_m(12.0))
    received = await daemon.collect(12.5)
    await sender
    first_f = kinds(received).index("R-F")
    # One cast: one run of depth reports, and the cast's own R-F after it.
    assert "R-M" not in kinds(received)[first_f:]
    # Every M after the cast gets R-O + R-F (the station is done): no new cast.
    after = kinds(received)[first_f + 1 :]
    assert set(after) <= {"R-O", "R-F"}
    assert after.count("R-F") >= 6
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    assert cast_rows(daemon) == [(1, "completed")]


async def test_corrupt_bytes_and_split_frames_are_survived(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    request = encode(ProbePositionRequest(7))
    stream = b"\x00\xffgarbage PR" + request[:3]
    await port.send(stream)
    await asyncio.sleep(0.05)
    for byte in request[3:]:  # the rest of the frame, one byte at a time
        await port.send(bytes([byte]))
        await asyncio.sleep(0.002)
    reply = await daemon.expect(ProbePosition, 1)
    assert reply is not None and reply.message.timestamp_s == 7
    # A bad checksum is dropped and the very next frame still answered.
    bad = bytes.fromhex("50 53 00 48 00 EC")
    await port.send(bad + encode(ProbePositionRequest(8)))
    reply = await daemon.expect(ProbePosition, 1)
    assert reply is not None and reply.message.timestamp_s == 8
    assert await daemon.expect(ProbePosition, 0.3, fail=False) is None  # nothing for the bad one
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    debug = [e for e in daemon.log_events() if e.get("event") == "corrupt frame"]
    assert any(
        e.get("kind") == "bad_checksum" and e.get("bytes") == "50 53 00 48 00 EC" for e in debug
    )


@pytest.mark.parametrize("signals", [1, 2], ids=["sigterm", "sigterm-twice"])
async def test_sigterm_mid_cast_brings_the_probe_home_then_exits(
    make_daemon: MakeDaemon, signals: int
) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack, 2)
    await asyncio.sleep(2.2)
    for _ in range(signals):  # a supervisor repeating SIGTERM must not abandon the probe
        daemon.send_signal(signal.SIGTERM)
        await asyncio.sleep(0.2)
    frames = await run_cast(daemon, timeout=10)
    depths = [r.message.depth_mm for r in frames if isinstance(r.message, DepthReport)]
    assert depths[-1] < depths[0] or depths[-1] == 0  # on its way up
    assert frames[-1].message.depth_mm == 0  # type: ignore[union-attr]
    assert await daemon.wait_exit() == 0
    assert cast_rows(daemon) == [(1, "aborted")]


async def test_a_second_sigint_stops_at_once_and_says_the_probe_may_be_down(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack, 2)
    await asyncio.sleep(2.0)
    daemon.send_signal(signal.SIGINT)
    await asyncio.sleep(0.2)
    daemon.send_signal(signal.SIGINT)
    assert await daemon.wait_exit(5) == 130
    assert await daemon.expect(Finished, 0.5, fail=False) is None
    assert any("probe may be down" in str(e.get("event")) for e in daemon.log_events())


async def test_the_port_vanishing_mid_cast_is_survived(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon({"cast": {"target_depth_m": 4.0}})
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack, 2)
    await daemon.expect(DepthReport, 2)
    # Pull the cable: the symlink goes, the old pty hangs up.
    port.detach()
    daemon.pty.unplug()
    await asyncio.sleep(2.0)
    daemon.pty.replug()  # a new pty behind the same path
    daemon.port = await FramePort.over_fd(daemon.pty.master_fd)
    frames = await run_cast(daemon, timeout=15)
    reports = [r for r in frames if isinstance(r.message, DepthReport)]
    assert reports, kinds(frames)
    assert frames[-1].message.depth_mm == 0  # type: ignore[union-attr]
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    # The cast went on while the port was gone, and kept recording.
    with sqlite3.connect(daemon.db) as db:
        samples = db.execute("SELECT COUNT(*) FROM samples WHERE cast_id = 1").fetchone()[0]
        events = [k for (k,) in db.execute("SELECT kind FROM events ORDER BY id")]
    assert samples >= 8
    assert "port_lost" in events
    assert events.count("port_opened") == 1
    assert "port_regained" in events
    assert events.index("port_lost") < events.index("port_regained")
    await port.close()


async def test_a_bad_config_file_exits_2_before_opening_anything(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon({"cast": {"target_depth_m": -1.0}})
    daemon.start()
    assert await daemon.wait_exit(10) == 2
    text = daemon.log_text()
    assert "cast.target_depth_m" in text and "-1" in text
    assert not daemon.db.exists()  # nothing opened, not even the journal


async def test_a_stranded_probe_is_reported_loudly_and_never_finished(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon({"winch": {"sim": {"fail_home": True}}, "cast": {"target_depth_m": 2.0}})
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack, 2)
    # 2 s down, 1 s dwell, the ascent jams at 0.5 m, the retry jams again: stranded.
    frames = await daemon.collect(9.0)
    assert "R-F" not in kinds(frames)
    # Stranded: R-L (the fault, for the ground station) in place of R-M, with the
    # last known depth, every period.
    tail = [r.message.depth_mm for r in frames[-3:] if isinstance(r.message, FaultReport)]
    assert tail == [500, 500, 500]
    alarms = [e for e in daemon.log_events() if "PROBE NOT HOME" in str(e.get("event"))]
    # Critical, and rate-limited: identical alarms each period pass once per window.
    assert 1 <= len(alarms) <= 2 and all(e["level"] == "critical" for e in alarms)
    # SIGTERM cannot bring it home: the daemon says so and exits without R-F.
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit(10) == 130
    assert await daemon.expect(Finished, 0.3, fail=False) is None
    assert any("NOT home" in str(e.get("event")) for e in daemon.log_events())
    assert cast_rows(daemon) == [(1, "unfinished")]


async def test_a_simulated_winch_not_asked_for_is_refused_before_anything_is_opened(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon({"winch": {"sim": {"allow_outside_simulation": False}}})
    daemon.start()
    assert await daemon.wait_exit(10) == 2
    text = daemon.log_text()
    assert 'cc-daemon: bad configuration: winch.backend = "sim" (from ' in text
    assert "a simulated winch would answer the autopilot" in text
    assert "winch.sim.allow_outside_simulation = true" in text
    assert not daemon.db.exists()


async def test_the_gpio_winch_without_gpio_pins_exits_saying_why(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon({"winch": {"backend": "gpio"}})  # a laptop: no lgpio, no GPIO chip
    daemon.start()
    assert await daemon.wait_exit(10) == 1
    assert "cc-daemon: cannot " in daemon.log_text() and "GPIO" in daemon.log_text()
    # The journal was checked at start (it could be opened), but the daemon never
    # started serving: no start recorded, no cast.
    if daemon.db.exists():
        with sqlite3.connect(daemon.db) as conn:
            kinds = [kind for (kind,) in conn.execute("SELECT kind FROM events")]
            assert "daemon_started" not in kinds
            assert conn.execute("SELECT count(*) FROM casts").fetchone() == (0,)


async def test_a_whole_cast_on_the_gpio_winch_with_mock_pins(make_daemon: MakeDaemon) -> None:
    gpio = {"pin_factory": "mock", "line_speed_m_s": 2.0, "stall_timeout_s": 1.0}
    daemon = make_daemon({"winch": {"backend": "gpio", "gpio": gpio}})
    await daemon.start_and_connect()
    await daemon.port.send(station())  # type: ignore[union-attr]
    frames = await run_cast(daemon)
    assert kinds(frames)[0] == "R-O" and kinds(frames)[-1] == "R-F"
    depths = [r.message.depth_mm for r in frames if isinstance(r.message, DepthReport)]
    assert max(depths) >= 2800  # 3 m, by the drum's count (0.14 m a pulse)
    last = frames[-1].message
    assert isinstance(last, Finished) and last.depth_mm == 0
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit(10) == 0
    events = daemon.log_events()
    warned = [e for e in events if str(e.get("event", "")).startswith("SIMULATED WINCH")]
    assert warned and warned[0]["level"] == "critical"
    assert any(e.get("event") == "winch home: limit switch closed" for e in events)
    with sqlite3.connect(daemon.db) as db:
        assert db.execute("SELECT winch_backend, simulated FROM sessions").fetchall() == [
            ("gpio-mock", 1)
        ]
        assert db.execute("SELECT outcome, winch_backend, simulated FROM casts").fetchall() == [
            ("completed", "gpio-mock", 1)
        ]
