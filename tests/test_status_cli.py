"""`cc-daemon status` in-process against an in-process daemon: the words a person
reads, the JSON a script reads, and the live view on a terminal and on a pipe."""

from __future__ import annotations

import asyncio
import io
import json
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.app import main
from cc_daemon.cli.status.client import StatusUnavailable, read_status
from cc_daemon.cli.status.view import render_text, watch
from cc_daemon.config import Settings
from cc_daemon.core.protocol import Telemetry
from cc_daemon.daemon.service import Daemon
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import FAST_CAST, merge, station
from tests.waitkit import DEADLINE_S, until


@pytest.fixture
async def running(tmp_path: Path) -> AsyncIterator[tuple[Daemon, FramePort, Path]]:
    pty = PtyPair(tmp_path / "tty")
    sock = tmp_path / "s.sock"
    config: dict[str, Any] = merge(
        FAST_CAST,
        {
            "serial": {"port": str(pty.path)},
            "store": {"path": str(tmp_path / "j.db")},
            "status": {"path": str(sock)},
        },
    )
    daemon = Daemon(Settings.model_validate(config))
    port = await FramePort.over_fd(pty.master_fd)
    task = asyncio.create_task(daemon.run())
    await asyncio.wait_for(daemon.ready.wait(), DEADLINE_S)
    # Looked at on the loop that serves it: once there, it is listening too.
    await until(sock.is_socket, "the status socket")
    yield daemon, port, sock
    daemon.request_shutdown()
    assert await asyncio.wait_for(task, DEADLINE_S) == 0
    await port.close()
    pty.close()


async def test_json_and_words(
    running: tuple[Daemon, FramePort, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    daemon, port, sock = running
    await port.send(Telemetry(99, -37260579, 404506308, 702385, 12_400, 96))
    await until(lambda: daemon.last_fix is not None, "the fix taken")
    assert await asyncio.to_thread(main, ["status", "--json", "--socket", str(sock)]) == 0
    # The in-process daemon's own log shares stdout: the document is the JSON line.
    out = capsys.readouterr().out.splitlines()
    doc = json.loads(next(line for line in out if line.startswith("{")))
    assert doc["daemon"]["state"] == "serving"
    assert doc["fix"]["frame"] == "P-T" and doc["fix"]["sonar_confidence_pct"] == 96
    assert doc["cast"] == {
        "phase": "idle",
        "cast_id": None,
        "planned_depth_m": None,
        "depth_m": 0,
        "fault_reported": None,  # the probe stranded: depth, fault, R-L sent
    }
    assert doc["winch"]["at_home"] is True and doc["winch"]["moving"] is False
    assert doc["journal"]["path"].endswith("j.db") and doc["journal"]["dropped_rows"] == 0

    assert await asyncio.to_thread(main, ["status", "--socket", str(sock)]) == 0
    words = capsys.readouterr().out
    assert f"UP on {daemon.link.port} at 9600 bit/s, 0 port losses" in words
    assert "sonar 12.40 m (96 %)" in words and "40.4506308, -3.7260579" in words
    assert "idle, probe at 0.00 m" in words and "sim: stopped, home" in words
    assert "journal   " in words and "writable, " in words


async def test_watch_on_a_terminal_and_a_pipe(running: tuple[Daemon, FramePort, Path]) -> None:
    _, _, sock = running

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    screen = Terminal()
    await asyncio.to_thread(
        watch, lambda: read_status(sock), interval_s=0.05, updates=2, stream=screen
    )
    assert "cc-daemon status" in screen.getvalue() and "counters" in screen.getvalue()
    pipe = io.StringIO()
    missing = sock.with_name("none.sock")
    await asyncio.to_thread(
        watch, lambda: read_status(missing), interval_s=0.05, updates=2, stream=pipe
    )
    assert pipe.getvalue().count("daemon not answering: no status socket at") == 2


def test_socket_from_the_configuration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "c.toml"
    config.write_text(f'[status]\npath = "{tmp_path / "x.sock"}"\n')
    assert main(["status", "--config", str(config)]) == 1
    assert f"no status socket at {tmp_path / 'x.sock'}" in capsys.readouterr().err
    config.write_text("[status]\nmax_clients = 0\n")
    assert main(["status", "--config", str(config)]) == 2  # a bad file given on purpose
    assert "status.max_clients = 0" in capsys.readouterr().err


def test_a_non_document_is_refused(tmp_path: Path) -> None:
    import socket
    import threading

    path = tmp_path / "junk.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as server:
        server.bind(str(path))
        server.listen()

        def answer() -> None:
            conn, _ = server.accept()
            conn.sendall(b"[1, 2]\n")
            conn.close()

        thread = threading.Thread(target=answer)
        thread.start()
        with pytest.raises(StatusUnavailable, match="not a status document"):
            read_status(path)
        thread.join()


async def test_stopping_is_shown_while_the_probe_comes_home(
    running: tuple[Daemon, FramePort, Path],
) -> None:
    daemon, port, sock = running
    await port.send(station())
    # The probe 2 m down: coming home takes 2 s, the margin to read the status in.
    await until(lambda: daemon.snapshot().probe_depth_m >= 2.0, "the probe 2 m down")
    daemon.request_shutdown()
    doc = await asyncio.to_thread(read_status, sock)
    assert doc["daemon"]["state"] == "stopping"
    assert doc["cast"]["phase"] != "idle" and doc["cast"]["depth_m"] > 0
    assert "STOPPING (bringing the probe home first)" in render_text(doc)
