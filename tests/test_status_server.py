"""The status server in-process: its bounds, its socket file, and the clock reading."""

from __future__ import annotations

import asyncio
import json
import socket
import stat
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.status.client import read_status
from cc_daemon.cli.status.view import render_text
from cc_daemon.daemon.status_server import SocketBusy, StatusServer
from cc_daemon.ground.clocksync import STA_UNSYNC, TIME_ERROR, clock_sync, from_adjtimex
from tests.waitkit import until


def nonblocking_client(path: Path) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(str(path))
    s.setblocking(False)
    return s


def _closed(client: socket.socket) -> bool:
    """Whether the server closed `client`'s connection (with nothing sent)."""
    try:
        data = client.recv(10)
    except BlockingIOError:
        return False  # still open and silent
    except ConnectionResetError:
        return True
    assert data == b""
    return True


async def test_a_reader_that_never_reads_is_cut_off_and_the_loop_runs(tmp_path: Path) -> None:
    # A document far larger than a socket buffer: the write must wait on the client.
    huge = {"blob": "x" * 8_000_000}
    server = StatusServer(tmp_path / "s.sock", lambda: huge, max_clients=1, client_timeout_s=0.5)
    await server.start()
    try:
        # Both connect before the loop runs again: it accepts them in one go, in order.
        stalled = nonblocking_client(server.path)
        refused = nonblocking_client(server.path)
        # The only slot is taken: the next client is closed unanswered, while the
        # stalled one is still being written to. A loop held by the stalled client
        # until its time-out would have freed the slot first and served the next one.
        await until(lambda: server.refused or server.cut_off, "the second client handled")
        assert (server.refused, server.served) == (1, 0)
        # Closed, not left open and silent (recv would raise BlockingIOError).
        await until(lambda: _closed(refused), "the refused client closed")
        await until(lambda: server.cut_off, "the stalled client cut off")
        assert (server.cut_off, server.refused, server.served) == (1, 1, 0)
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
