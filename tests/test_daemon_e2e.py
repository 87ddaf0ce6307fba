"""The daemon as a real subprocess on a pty pair, driven by a test autopilot.

Every test speaks real frames over a real pseudo-terminal to `python -m
cc_daemon`, and checks what came back (and, where it matters, the journal
file and the exit status).
"""

from __future__ import annotations

import asyncio
import contextlib
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
    Message,
    ProbePosition,
    ProbePositionRequest,
    Telemetry,
    encode,
)
from cc_daemon.sim.port import FramePort, Received
from tests.daemonkit import (
    WAIT_S,
    DaemonProcess,
    collect_until,
    frames_before_reply,
    nth,
    station,
)

pytestmark = pytest.mark.slow
MakeDaemon = Callable[..., DaemonProcess]


def kinds(received: list[Received]) -> list[str]:
    return [r.message.frame for r in received]


async def run_cast(daemon: DaemonProcess, timeout: float = WAIT_S) -> list[Received]:
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


def deeper_than(depth_mm: int) -> Callable[[Message], bool]:
    """A depth report from below `depth_mm`: the probe is that far down."""
    return lambda m: isinstance(m, DepthReport) and m.depth_mm >= depth_mm


def cast_rows(daemon: DaemonProcess) -> list[tuple[object, ...]]:
    with sqlite3.connect(daemon.db) as db:
        return db.execute("SELECT id, outcome FROM casts ORDER BY id").fetchall()


async def test_a_whole_cast(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    await port.send(Telemetry(99, -37260579, 404506308, 702385, 30_000, 100))
    await port.send(station())
    frames = await run_cast(daemon)
    assert frames[0].message == Ack(frames[0].message.timestamp_s)
    reports = [r for r in frames if isinstance(r.message, DepthReport)]
    depths = [r.message.depth_mm for r in reports]
    deepest = depths.index(max(depths))
    assert max(depths) == 3000
    assert depths[:deepest] == sorted(depths[:deepest])
    assert depths[deepest:] == sorted(depths[deepest:], reverse=True)
    finished = frames[-1].message
    assert isinstance(finished, Finished) and finished.depth_mm == 0
    # Timestamps follow the autopilot's clock (M carried t=100), and the reports
    # come one a period (1 s) at most, about 7 for a ~7 s cast: never a burst, on
    # however slow a machine (a late report is one report, not several). The
    # latencies and the cadence's jitter are figures of benchmarks/daemon.py.
    assert frames[0].message.timestamp_s == 100
    stamps = [r.message.timestamp_s for r in reports]
    assert stamps == sorted(stamps) and 101 <= stamps[0] <= stamps[-1] <= finished.timestamp_s
    assert 3 <= len(reports) <= finished.timestamp_s - 100 + 1
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
    frames = await collect_until(port, lambda m: isinstance(m, Finished))
    assert kinds(frames) == ["R-O", "R-F"]  # no cast: not a single depth report
    assert frames[1].message == Finished(frames[1].message.timestamp_s, 0)
    skipped = await daemon.logged("cast skipped")
    assert skipped["event"] == "cast skipped: station too shallow"


async def test_s_during_a_cast_gets_the_current_depth(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon({"cast": {"target_depth_m": 8.0}})  # 8 s of descent to ask in
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack)
    before = await collect_until(port, deeper_than(1000))
    await port.send(ProbePositionRequest(500))
    until_reply = await collect_until(port, lambda m: isinstance(m, ProbePosition))
    reply = until_reply[-1].message
    after = await daemon.expect(DepthReport)
    assert isinstance(reply, ProbePosition) and after is not None
    assert reply.timestamp_s == 500
    # The probe on its way down: the depth of the moment, between the reports either side.
    last_report = [r.message for r in before + until_reply if isinstance(r.message, DepthReport)]
    assert last_report[-1].depth_mm <= reply.depth_mm <= after.message.depth_mm  # type: ignore[union-attr]
    assert 1000 <= reply.depth_mm < 8000


async def test_m_resent_every_half_second_makes_exactly_one_cast(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()

    async def resend_m() -> None:
        while True:
            await port.send(station())
            await asyncio.sleep(0.5)

    sender = asyncio.create_task(resend_m())
    try:  # the cast's own R-F, and six for Ms after it
        received = await collect_until(port, nth(Finished, 7))
    finally:
        sender.cancel()
        with contextlib.suppress(asyncio.CancelledError):
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
    reply = await daemon.expect(ProbePosition)
    assert reply is not None and reply.message.timestamp_s == 7
    # A bad checksum is dropped and the very next frame still answered.
    bad = bytes.fromhex("50 53 00 48 00 EC")
    await port.send(bad + encode(ProbePositionRequest(8)))
    reply = await daemon.expect(ProbePosition)
    assert reply is not None and reply.message.timestamp_s == 8
    assert await frames_before_reply(port) == []  # nothing for the bad one
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
    await daemon.expect(Ack)
    down = await collect_until(port, deeper_than(2000))
    daemon.send_signal(signal.SIGTERM)
    await daemon.logged("signal received: bringing the probe home")
    if signals == 2:  # a supervisor repeating SIGTERM must not abandon the probe
        daemon.send_signal(signal.SIGTERM)
        await daemon.logged("already shutting down")
    frames = await run_cast(daemon)
    depths = [r.message.depth_mm for r in down + frames if isinstance(r.message, DepthReport)]
    assert depths[-1] < max(depths) or depths[-1] == 0  # on its way up
    assert frames[-1].message.depth_mm == 0  # type: ignore[union-attr]
    assert await daemon.wait_exit() == 0
    assert cast_rows(daemon) == [(1, "aborted")]


async def test_a_second_sigint_stops_at_once_and_says_the_probe_may_be_down(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon()
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack)
    await collect_until(port, deeper_than(1000))
    daemon.send_signal(signal.SIGINT)
    # Heard before the second is sent: two signals pending at once would be one.
    await daemon.logged("signal received: bringing the probe home")
    daemon.send_signal(signal.SIGINT)
    assert await daemon.wait_exit() == 130
    # It has exited: all it wrote is in the pty already.
    assert await daemon.expect(Finished, 1.0, fail=False) is None
    assert any("probe may be down" in str(e.get("event")) for e in daemon.log_events())


async def test_the_port_vanishing_mid_cast_is_survived(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon({"cast": {"target_depth_m": 4.0}})
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack)
    await daemon.expect(DepthReport)
    # Pull the cable: the symlink goes, the old pty hangs up.
    port.detach()
    daemon.pty.unplug()
    await daemon.logged("serial port lost")
    daemon.pty.replug()  # a new pty behind the same path
    daemon.port = await FramePort.over_fd(daemon.pty.master_fd)
    frames = await run_cast(daemon)
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
    assert await daemon.wait_exit() == 2
    text = daemon.log_text()
    assert "cast.target_depth_m" in text and "-1" in text
    assert not daemon.db.exists()  # nothing opened, not even the journal


async def test_a_stranded_probe_is_reported_loudly_and_never_finished(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon({"winch": {"sim": {"fail_home": True}}, "cast": {"target_depth_m": 2.0}})
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack)
    # 2 s down, 1 s dwell, the ascent jams at 0.5 m, the retry jams again: stranded.
    frames = await collect_until(port, nth(FaultReport, 3))
    assert "R-F" not in kinds(frames)
    # Stranded: R-L (the fault, for the ground station) in place of R-M, with the
    # last known depth, every period.
    stranded = kinds(frames)[kinds(frames).index("R-L") :]
    assert stranded == ["R-L", "R-L", "R-L"]
    assert [r.message.depth_mm for r in frames[-3:]] == [500, 500, 500]  # type: ignore[union-attr]
    await daemon.logged("PROBE NOT HOME")
    alarms = [e for e in daemon.log_events() if "PROBE NOT HOME" in str(e.get("event"))]
    # Critical, and rate-limited: identical alarms each period pass once per window.
    assert 1 <= len(alarms) <= 2 and all(e["level"] == "critical" for e in alarms)
    # SIGTERM cannot bring it home: the daemon says so and exits without R-F.
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 130
    # It has exited: all it wrote is in the pty already.
    assert await daemon.expect(Finished, 1.0, fail=False) is None
    assert any("NOT home" in str(e.get("event")) for e in daemon.log_events())
    assert cast_rows(daemon) == [(1, "unfinished")]


async def test_a_simulated_winch_not_asked_for_is_refused_before_anything_is_opened(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon({"winch": {"sim": {"allow_outside_simulation": False}}})
    daemon.start()
    assert await daemon.wait_exit() == 2
    text = daemon.log_text()
    assert 'cc-daemon: bad configuration: winch.backend = "sim" (from ' in text
    assert "a simulated winch would answer the autopilot" in text
    assert "winch.sim.allow_outside_simulation = true" in text
    assert not daemon.db.exists()


async def test_the_gpio_winch_without_gpio_pins_exits_saying_why(make_daemon: MakeDaemon) -> None:
    daemon = make_daemon({"winch": {"backend": "gpio"}})  # a laptop: no lgpio, no GPIO chip
    daemon.start()
    assert await daemon.wait_exit() == 1
    assert "cc-daemon: cannot " in daemon.log_text() and "GPIO" in daemon.log_text()
    # The journal was checked at start (it could be opened), but the daemon never
    # started serving: no start recorded, no cast.
    if daemon.db.exists():
        with sqlite3.connect(daemon.db) as conn:
            kinds = [kind for (kind,) in conn.execute("SELECT kind FROM events")]
            assert "daemon_started" not in kinds
            assert conn.execute("SELECT count(*) FROM casts").fetchone() == (0,)


async def test_a_whole_cast_on_the_gpio_winch_with_mock_pins(make_daemon: MakeDaemon) -> None:
    # No fault is wanted here: the stall and loop watchdogs get times a loaded
    # machine's pauses never reach (they cost nothing when nothing stalls).
    gpio = {
        "pin_factory": "mock",
        "line_speed_m_s": 2.0,
        "stall_timeout_s": 5.0,
        "loop_watchdog_s": 5.0,
    }
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
    assert await daemon.wait_exit() == 0
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
