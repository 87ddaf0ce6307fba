"""A missing serial device: waited for, and said again at a slowing interval."""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import re
import socket
import time
from pathlib import Path

import pytest

from cc_daemon.drivers.link import SerialLink
from cc_daemon.ground.logsetup import configure_logging
from cc_daemon.ground.waiting import WaitReport
from cc_daemon.sim.pty import PtyPair
from tests.waitkit import DEADLINE_S, until


def test_reports_come_at_a_slowing_interval_with_a_count() -> None:
    report = WaitReport(first_s=10.0, factor=2.0, max_s=40.0)
    due = [t for t in range(0, 200) if report.failed(float(t), 1_700_000_000.0 + t)]
    # One attempt a second from t=0: reports at 10 s, then 20 s, 40 s, 40 s... apart.
    assert due == [10, 30, 70, 110, 150, 190]
    assert report.attempts == 200
    since = time.strftime("%H:%M:%S", time.localtime(1_700_000_000.0))
    assert (
        report.message("/dev/ttyUSB7")
        == f"still waiting for /dev/ttyUSB7: 200 attempts since {since}"
    )


def test_the_device_appearing_starts_the_next_wait_afresh() -> None:
    report = WaitReport(first_s=1.0, max_s=1.0)
    assert [report.failed(t, t) for t in (0.0, 0.5, 1.0)] == [False, False, True]
    report.reset()
    assert (report.attempts, report.waiting) == (0, False)
    assert [report.failed(t, t) for t in (5.0, 5.5, 6.0)] == [False, False, True]
    assert report.since_wall == 5.0


def test_bad_schedules_are_refused() -> None:
    with pytest.raises(ValueError, match="first_s"):
        WaitReport(first_s=0)


async def test_a_link_waiting_for_a_missing_device_keeps_saying_so(tmp_path: Path) -> None:
    out = io.StringIO()
    configure_logging("json", "info", out)
    path = tmp_path / "ttyUSB7"
    said: list[str] = []
    link = SerialLink(
        str(path),
        on_data=lambda _: None,
        on_waiting=said.append,
        reconnect_initial_s=0.02,
        reconnect_max_s=0.05,
        wait_report=WaitReport(first_s=0.2, factor=2.0, max_s=0.4),
    )
    task = asyncio.create_task(link.run())
    try:
        # Retried every 0.02-0.05 s and said again 0.2 s, then 0.4 s apart, each report
        # with a growing count. (When each is due, on the times given: the tests above.)
        await until(lambda: len(said) >= 3 and link.waiting.attempts >= 20, "retried, and said")
        counts = [
            int(re.fullmatch(rf"still waiting for {path}: (\d+) attempts since [\d:]{{8}}", s)[1])
            for s in said
        ]  # type: ignore[index]
        assert counts == sorted(counts) and counts[0] < counts[-1]
        logged = [json.loads(line) for line in out.getvalue().splitlines()]
        first, *later = [e["event"] for e in logged]
        assert first == "cannot open serial port"  # with its reason
        assert later == said
        pty = PtyPair(path)  # the adapter is plugged in
        try:
            await until(lambda: link.up, "the link up")
            assert link.waiting.attempts == 0
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            pty.close()
    finally:
        task.cancel()


async def test_the_daemon_counts_the_wait_and_says_it_in_the_systemd_status(
    tmp_path: Path,
) -> None:
    from cc_daemon.cli.status.view import render_text
    from cc_daemon.config import Settings
    from cc_daemon.daemon.service import Daemon
    from cc_daemon.daemon.status_report import status_document
    from cc_daemon.daemon.systemd import SystemdNotifier

    sock_path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(sock_path))
        server.setblocking(False)
        settings = Settings.model_validate(
            {
                "serial": {
                    "port": str(tmp_path / "ttyUSB7"),
                    "reconnect_initial_s": 0.05,
                    "reconnect_max_s": 0.05,
                },
                "store": {"path": str(tmp_path / "j.db")},
            }
        )
        daemon = Daemon(settings, notifier=SystemdNotifier(str(sock_path)))
        daemon.link.waiting = WaitReport(first_s=0.2, max_s=0.2)
        task = asyncio.create_task(daemon.run())
        statuses: list[str] = []

        def said_twice() -> bool:  # what systemd was told, as it comes
            with contextlib.suppress(BlockingIOError):
                while True:
                    statuses.append(server.recv(4096).decode())
            return len([s for s in statuses if "still waiting for" in s]) >= 2

        try:
            await until(said_twice, "two still-waiting statuses for systemd")
            await until(lambda: daemon.snapshot().port_open_attempts >= 10, "ten attempts")
            # ... and the status document (`cc-daemon status`) says so.
            doc = status_document(daemon.status_inputs())
            assert doc["link"]["up"] is False and doc["link"]["open_attempts"] >= 10
            assert f"{doc['link']['open_attempts']} attempts to open it" in render_text(doc)
            waiting = [s for s in statuses if "still waiting for" in s]
            assert waiting[-1].startswith(f"STATUS=still waiting for {tmp_path / 'ttyUSB7'}: ")
        finally:
            daemon.request_shutdown()
            await asyncio.wait_for(task, DEADLINE_S)
