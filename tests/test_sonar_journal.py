"""The daemon's own sonar in the journal: impossible readings flagged, a flood thinned.

A Ping1D's confidence above 100 % and its all-ones distance (0xFFFFFFFF, "no
distance") are stored as they came and never trusted for a bottom. A stream of
1000 readings a second goes into a real journal at `sonar.journal_rate_hz`,
the rest summarised in events: the file's growth is measured.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import time
from pathlib import Path

from cc_daemon.config import Settings
from cc_daemon.core.cast.bottom import NO_DISTANCE_MM, ONBOARD, Sounding, freshest_bottom
from cc_daemon.core.cast.plan import CastPlan, plan_cast
from cc_daemon.daemon.sonar import OnboardSonar
from cc_daemon.drivers.sonar import ping
from cc_daemon.drivers.sonar.client import SonarClient, SonarReading
from cc_daemon.store import Journal
from tests.daemonkit import station


def test_impossible_readings_arrive_as_they_are_and_flagged() -> None:
    client = SonarClient()
    data = ping.encode(ping.DISTANCE_SIMPLE, distance=2500, confidence=150) + ping.encode(
        ping.DISTANCE_SIMPLE, distance=NO_DISTANCE_MM, confidence=100
    )
    over, sentinel = client.feed(1.0, data)
    assert (over.distance_mm, over.confidence_pct, over.valid) == (2500, 150, False)
    assert (sentinel.distance_mm, sentinel.confidence_pct, sentinel.valid) == (
        4294967295, 100, False,
    )  # fmt: skip
    assert SonarReading(2500, 100, 1.0).valid


def test_impossible_readings_are_never_a_bottom() -> None:
    for mm, conf in ((NO_DISTANCE_MM, 100), (2500, 101), (2500, 255)):
        assert freshest_bottom([Sounding(ONBOARD, mm, conf, 1.0)], 1.0,
                               min_confidence=70, max_age_s=1.0) is None  # fmt: skip
    settings = Settings.model_validate({"cast": {"target_depth_m": 10.0}}).cast
    plan = plan_cast(station(sonar_mm=NO_DISTANCE_MM, confidence=100), settings, 100.0)
    assert isinstance(plan, CastPlan)
    # No bottom taken from it ("target" here; main's planner then casts "blind").
    assert plan.water_depth_m is None and plan.limited_by != "bottom"
    trusted = plan_cast(station(sonar_mm=8_000, confidence=100), settings, 100.0)
    assert isinstance(trusted, CastPlan) and trusted.water_depth_m == 8.0


def _journal_growth(tmp_path: Path, name: str, per_s: int, seconds: int) -> tuple[int, Path]:
    db = tmp_path / f"{name}.db"
    journal = Journal(db)
    journal.open()
    empty = db.stat().st_size + _side(db)
    settings = Settings.model_validate({"sonar": {"port": str(tmp_path / "ttyPING")}})
    sonar = OnboardSonar(settings.sonar, clock=None, journal=lambda: journal)  # type: ignore[arg-type]
    for k in range(per_s * seconds):
        conf = 255 if k % 7 == 0 else 90  # some impossible ones among them
        sonar._record(SonarReading(3000 + k % 500, conf, 1000.0 + k / per_s))
    sonar._summarise(1000.0 + seconds, everything=True)
    journal.close()
    return db.stat().st_size + _side(db) - empty, db


def _side(db: Path) -> int:
    wal = db.with_name(db.name + "-wal")
    return wal.stat().st_size if wal.exists() else 0


def test_a_1000_per_second_stream_is_thinned_and_summarised(tmp_path: Path) -> None:
    growth, db = _journal_growth(tmp_path, "flood", 1000, 60)
    with sqlite3.connect(db) as conn:
        rows = conn.execute("SELECT distance_mm, confidence_pct FROM sonar_readings")
        rows = rows.fetchall()
        events = conn.execute("SELECT kind, detail_json FROM events WHERE kind LIKE 'sonar_%'")
        events = [(k, json.loads(d)) for k, d in events.fetchall()]
    assert 239 <= len(rows) <= 241  # 4 a second, the stream's nominal rate
    assert any(conf == 255 for _, conf in rows)  # stored as it came
    kinds = [k for k, _ in events]
    assert kinds.count("sonar_thinning_started") == 1
    summaries = [d for k, d in events if k == "sonar_thinned"]
    assert sum(d["count"] for d in summaries) + len(rows) == 60_000
    assert min(d["min_distance_mm"] for d in summaries) == 3001  # 3000 is always kept
    assert max(d["max_distance_mm"] for d in summaries) == 3499
    assert growth <= 1_000_000, f"{growth} bytes in a minute"
    print(f"journal growth under 1000 readings/s for 60 s: {growth} bytes")


def test_a_nominal_stream_is_journaled_whole(tmp_path: Path) -> None:
    _, db = _journal_growth(tmp_path, "nominal", 4, 30)
    with sqlite3.connect(db) as conn:
        (n,) = conn.execute("SELECT COUNT(*) FROM sonar_readings").fetchone()
        (events,) = conn.execute(
            "SELECT COUNT(*) FROM events WHERE kind LIKE 'sonar_thin%'"
        ).fetchone()
    assert n == 120 and events == 0


def test_thinning_that_stops_and_starts_again_is_said_again(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    journal = Journal(db)
    journal.open()
    settings = Settings.model_validate({"sonar": {"port": str(tmp_path / "ttyPING")}})
    sonar = OnboardSonar(settings.sonar, clock=None, journal=lambda: journal)  # type: ignore[arg-type]
    t = 0.0
    for _ in range(1000):  # a burst: 100 a second for 10 s
        t += 0.01
        sonar._record(SonarReading(2000, 90, t))
    for _ in range(600):  # then the nominal 4 a second for 150 s
        t += 0.25
        sonar._record(SonarReading(2000, 90, t))
    for _ in range(100):  # and another burst
        t += 0.01
        sonar._record(SonarReading(2000, 90, t))
    sonar._summarise(t, everything=True)
    journal.close()
    with sqlite3.connect(db) as conn:
        kinds = [k for (k,) in conn.execute("SELECT kind FROM events ORDER BY id")]
        details = [json.loads(d) for (d,) in conn.execute(
            "SELECT detail_json FROM events WHERE kind = 'sonar_thinned' ORDER BY id")]  # fmt: skip
    assert [k for k in kinds if k.startswith("sonar_thin")] == [
        "sonar_thinning_started", "sonar_thinned", "sonar_thinning_started", "sonar_thinned",
    ]  # fmt: skip
    assert sum(d["count"] for d in details) == 1000 - 40 + 100 - 4


async def test_a_real_ping_streaming_fast_over_a_pty_is_thinned(tmp_path: Path) -> None:
    """The simulated Ping1D streaming every millisecond, read by the daemon's own
    reader over a real pty into a real journal: rows at the journal rate only."""
    import asyncio

    from cc_daemon.ground.clock import SystemClock
    from cc_daemon.sim.ping1d import Echo, Ping1DDevice, Ping1DServer
    from cc_daemon.sim.pty import PtyPair

    pair = PtyPair(tmp_path / "ttyPING")
    server = await Ping1DServer.over_fd(
        pair.master_fd, Ping1DDevice(lambda: Echo(3000, 95), interval_s=0.001)
    )
    db = tmp_path / "j.db"
    journal = Journal(db)
    journal.open()
    settings = Settings.model_validate({"sonar": {"port": str(pair.path)}})
    sonar = OnboardSonar(settings.sonar, clock=SystemClock(), journal=lambda: journal)
    began = time.monotonic()
    task = asyncio.create_task(sonar.run())
    try:
        async with asyncio.timeout(60):  # far more than the journal's 4 a second heard
            while sonar.reader.client.readings <= 300:  # noqa: ASYNC110 - counted by the reader
                await asyncio.sleep(0.05)
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        await server.close()
        pair.close()
        journal.close()
    ran_s = time.monotonic() - began
    heard = sonar.reader.client.readings
    with sqlite3.connect(db) as conn:
        (rows,) = conn.execute("SELECT COUNT(*) FROM sonar_readings").fetchone()
        summaries = [json.loads(d) for (d,) in conn.execute(
            "SELECT detail_json FROM events WHERE kind = 'sonar_thinned'")]  # fmt: skip
        (started,) = conn.execute(
            "SELECT COUNT(*) FROM events WHERE kind = 'sonar_thinning_started'"
        ).fetchone()
    assert heard > 300, heard  # far faster than the nominal 4 a second
    assert rows <= 4 * ran_s + 2, (rows, ran_s)
    assert started == 1 and sum(d["count"] for d in summaries) + rows == heard


def test_a_kilometre_or_more_is_no_bottom_and_no_echo_is_a_true_report() -> None:
    assert not SonarReading(1_000_000, 90, 0.0).valid
    assert SonarReading(999_999, 90, 0.0).valid
    assert SonarReading(0, 0, 0.0).valid  # a dropout: a true report of no echo
