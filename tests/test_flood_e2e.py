"""A babbling autopilot against the daemon subprocess: the journal takes telemetry at
`store.telemetry_rate_hz`, counts the rest, and every P-S is still answered."""

from __future__ import annotations

import asyncio
import json
import signal
import sqlite3
import time
from collections.abc import Callable

import pytest

from cc_daemon.core.protocol import ProbePosition, ProbePositionRequest, Telemetry, encode
from tests.daemonkit import DaemonProcess

pytestmark = pytest.mark.slow
MakeDaemon = Callable[..., DaemonProcess]


async def test_a_flood_of_fixes_is_journaled_at_the_configured_rate(
    make_daemon: MakeDaemon,
) -> None:
    daemon = make_daemon({"store": {"telemetry_rate_hz": 2.0}})
    port = await daemon.start_and_connect()
    burst = b"".join(
        encode(Telemetry(n, -37260579, 404506308 + n, 702385, 8219, 100)) for n in range(100)
    )
    sent = answered = 0
    began = time.monotonic()
    while time.monotonic() - began < 3.0:  # some 30,000 fixes in 3 s
        await port.send(burst)
        sent += 100
        await port.send(ProbePositionRequest(5))
        answered += await daemon.expect(ProbePosition) is not None
        await asyncio.sleep(0.01)
    elapsed = time.monotonic() - began
    daemon.send_signal(signal.SIGTERM)
    assert await daemon.wait_exit() == 0
    assert answered == sent // 100  # every P-S answered during the flood
    with sqlite3.connect(daemon.db) as db:
        fixes = db.execute("SELECT count(*) FROM fixes").fetchone()[0]
        thinned = [
            json.loads(detail)
            for (detail,) in db.execute(
                "SELECT detail_json FROM events WHERE kind = 'telemetry_thinned'"
            )
        ]
    # At most one fix per half second of the run (the answering checks add a few).
    assert fixes <= 2 * (elapsed + 2) + 2, fixes
    assert sum(t["dropped"] for t in thinned) + fixes >= sent
