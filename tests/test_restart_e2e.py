"""Restart after kill -9 mid-cast: the interrupted station is released (issue 19).

The daemon is a real subprocess on a pty; the test is the autopilot, waiting at
the station as the firmware does (no timeout). It is killed with SIGKILL mid-cast
and started again on the same journal and the same pty: the new run journals
what the old one left and, with the probe verified home, sends R-F."""

from __future__ import annotations

import json
import signal
import sqlite3

import pytest

from cc_daemon.core.protocol import Ack, DepthReport, FaultReport, Finished
from tests.daemonkit import START_S, station
from tests.test_daemon_e2e import MakeDaemon
from tests.waitkit import until

pytestmark = pytest.mark.slow


async def test_a_station_interrupted_by_kill_9_is_released_on_restart(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon({"cast": {"target_depth_m": 5.0}})
    port = await daemon.start_and_connect()
    await port.send(station())
    await daemon.expect(Ack)
    for _ in range(3):  # well into the descent
        await daemon.expect(DepthReport)
    daemon.send_signal(signal.SIGKILL)
    assert await daemon.wait_exit() == -signal.SIGKILL
    # The autopilot waits at the station, saying nothing, as the firmware does.
    daemon.start()
    got = await daemon.expect(Finished, START_S)
    assert got is not None and isinstance(got.message, Finished)
    assert got.message.depth_mm == 0
    assert not any(isinstance(r.message, FaultReport) for r in port.received)

    def recovered() -> list[tuple[str, str]] | None:
        """The events, once the writer has committed the recovery's (it is a thread)."""
        with sqlite3.connect(daemon.db) as db:
            rows = db.execute("SELECT kind, detail_json FROM events ORDER BY id").fetchall()
        return rows if any(kind == "cast_recovered" for kind, _ in rows) else None

    events = await until(recovered, what="cast_recovered journaled")
    kinds = [kind for kind, _ in events]
    with sqlite3.connect(daemon.db) as db:
        [(outcome,)] = db.execute("SELECT outcome FROM casts").fetchall()
    assert outcome == "unfinished"  # marked by the journal; the R-F does not rewrite it
    assert kinds.count("daemon_started") == 2 and "daemon_died" in kinds
    interrupted = json.loads(dict(events)["cast_interrupted"])
    assert interrupted["cast_id"] == 1 and interrupted["last_depth_m"] >= 1.0
    recovered = json.loads(dict(events)["cast_recovered"])
    assert recovered == {"cast_id": 1, "rf_sent": True}
    assert kinds.index("cast_interrupted") < kinds.index("cast_recovered")
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
