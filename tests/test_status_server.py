"""The status server in-process: its bounds, its socket file, and the clock reading."""

from __future__ import annotations

import asyncio
import json
import socket
import stat
import time
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.status.client import read_status
from cc_daemon.cli.status.view import render_text
from cc_daemon.daemon.status_server import SocketBusy, StatusServer
from cc_daemon.ground.clocksync import STA_UNSYNC, TIME_ERROR, clock_sync, from_adjtimex


async def max_loop_gap(seconds: float) -> float:
    """The longest the event loop went without running a 10 ms ticker."""
    gap = 0.0
    last = time.monotonic()
    end = last + seconds
    while (now := time.monotonic()) < end:
        gap = max(gap, now - last)
        last = now
        await asyncio.sleep(0.01)
    return gap


def nonblocking_client(path: Path) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(str(path))
    s.setblocking(False)
    return s


async def test_a_reader_that_never_reads_is_cut_off_and_the_loop_runs(tmp_path: Path) -> None:
    # A document far larger than a socket buffer: the write must wait on the client.
    huge = {"blob": "x" * 8_000_000}
    server = StatusServer(tmp_path / "s.sock", lambda: huge, max_clients=1, client_timeout_s=0.5)
    await server.start()
    try:
        stalled = nonblocking_client(server.path)
        gap = await max_loop_gap(0.3)
        # The only slot is taken: the next client is closed unanswered.
        refused = nonblocking_client(server.path)
        await asyncio.sleep(0.1)
        try:
            data = refused.recv(10)  # still open and silent would raise BlockingIOError
        except ConnectionResetError:
            data = b""
        assert data == b""
        for _ in range(200):  # past client_timeout_s, however loaded the machine (10 s)
            if server.cut_off:
                break
            await asyncio.sleep(0.05)
        assert (server.cut_off, server.refused, server.served) == (1, 1, 0)
        # A loop waiting on the stalled client would be still for client_timeout_s
        # (0.5 s); what is left is building the 8 MB document, slower on a loaded machine.
        assert gap < 0.4
        stalled.close()
        refused.close()
        # The slot is free again.
        small = StatusServer(tmp_path / "t.sock", lambda: {"ok": 1})
        await small.start()
        assert await asyncio.to_thread(read_status, small.path) == {"ok": 1}
        await small.close()
    finally:
        await server.close()


async def test_socket_mode_stale_and_busy_paths(tmp_path: Path) -> None:
    path = tmp_path / "s.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as dead:
        dead.bind(str(path))  # a socket left by a daemon that died
    server = StatusServer(path, lambda: {"n": 1})
    await server.start()
    try:
        assert stat.S_IMODE(path.stat().st_mode) == 0o660
        assert await asyncio.to_thread(read_status, path) == {"n": 1}
        second = StatusServer(path, lambda: {"n": 2})
        with pytest.raises(SocketBusy, match="another process answers"):
            await second.start()
        assert await asyncio.to_thread(read_status, path) == {"n": 1}
    finally:
        await server.close()
    assert not path.exists()
    path.write_text("not a socket")
    with pytest.raises(SocketBusy, match="not a socket"):
        await StatusServer(path, dict).start()
    assert path.read_text() == "not a socket"


async def test_a_failing_document_is_reported_not_raised(tmp_path: Path) -> None:
    def broken() -> dict[str, Any]:
        raise RuntimeError("snapshot failed")

    server = StatusServer(tmp_path / "s.sock", broken)
    await server.start()
    try:
        doc = await asyncio.to_thread(read_status, server.path)
        assert doc == {"error": "RuntimeError: snapshot failed"}
    finally:
        await server.close()


def test_adjtimex_interpretation() -> None:
    synced = from_adjtimex(0, 0x2001, 25_000)
    assert (synced.synchronised, synced.max_error_s, synced.source) == (True, 0.025, "adjtimex")
    assert from_adjtimex(0, STA_UNSYNC, 16_000_000).synchronised is False
    assert from_adjtimex(TIME_ERROR, 0, 16_000_000).synchronised is False


def test_clock_sync_answers_something_real() -> None:
    sync = clock_sync()
    assert sync.source in ("adjtimex", "timesyncd")
    assert sync.synchronised in (True, False)
    assert json.dumps(sync.as_dict())


def test_unknown_sections_are_shown_as_they_come() -> None:
    text = render_text({"jog": {"state": "idle"}, "link": {"up": False, "port": "/dev/x"}})
    assert 'jog       {"state": "idle"}' in text
    assert "DOWN on /dev/x" in text and "last fix  none yet" in text
