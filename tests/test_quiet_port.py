"""An open port that carries nothing is said soon, then ever less often; a frame ends it."""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
from pathlib import Path

from cc_daemon.config import Settings
from cc_daemon.core.protocol import Telemetry, encode
from cc_daemon.daemon.quiet_port import QuietPort
from cc_daemon.daemon.service import Daemon
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import WAIT_S
from tests.waitkit import until


def test_silence_is_said_after_first_s_then_at_doubling_intervals() -> None:
    quiet = QuietPort(first_s=5.0, max_s=20.0)
    assert quiet.due(100.0, "/dev/ttyS0") is None  # closed: nothing to say
    quiet.opened(100.0)
    assert quiet.due(104.9, "/dev/ttyS0") is None
    said = quiet.due(105.0, "/dev/ttyS0")
    assert said == (
        "nothing heard from the autopilot on /dev/ttyS0 for 5 s "
        "(check the wiring, that the autopilot is on, and serial.port)"
    )
    times = [t for t in range(106, 200) if quiet.due(float(t), "/dev/ttyS0")]
    assert times == [115, 135, 155, 175, 195]  # 10 s, then 20 s: the cap


def test_only_corrupt_frames_point_at_the_baud_rate() -> None:
    quiet = QuietPort(first_s=1.0)
    quiet.opened(0.0)
    quiet.corrupt()
    said = quiet.due(1.0, "/dev/serial0")
    assert said is not None and "1 corrupt frames (check serial.baudrate" in said


def test_a_readable_frame_ends_it_and_a_reopened_port_starts_over() -> None:
    quiet = QuietPort(first_s=1.0)
    quiet.opened(0.0)
    quiet.heard()
    assert quiet.due(50.0, "p") is None
    quiet.closed()
    quiet.opened(60.0)
    assert quiet.due(61.0, "p") is not None


def _drain(server: socket.socket) -> list[str]:
    got = []
    with contextlib.suppress(BlockingIOError):
        while True:
            got.append(server.recv(4096).decode())
    return [s for s in got if "nothing heard from the autopilot" in s]


async def test_the_daemon_says_it_in_the_systemd_status_until_a_frame_arrives(
    tmp_path: Path,
) -> None:
    sock_path = tmp_path / "notify.sock"
    with (
        socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server,
        PtyPair(tmp_path / "ttyS0") as pty,
    ):
        server.bind(str(sock_path))
        server.setblocking(False)
        settings = Settings.model_validate(
            {"serial": {"port": str(pty.path)}, "store": {"path": str(tmp_path / "j.db")}}
        )
        daemon = Daemon(settings, notifier=SystemdNotifier(str(sock_path)))
        daemon._housekeeping._quiet = QuietPort(first_s=0.3, max_s=0.3)
        task = asyncio.create_task(daemon.run())
        try:
            await asyncio.wait_for(daemon.ready.wait(), WAIT_S)
            said: list[str] = []

            def silence_said() -> bool:
                said.extend(_drain(server))
                return bool(said)

            await until(silence_said, what="the silence said")
            os.write(pty.master_fd, encode(Telemetry(1, -37260579, 404506308, 0, 6000, 90)))
            await until(lambda: daemon.frames_in == 1, what="the frame heard")
            _drain(server)  # what was said before the daemon heard it
            # Heard: nothing due any more, and nothing said over several of the
            # 0.3 s intervals (on a slow machine, over fewer: never a false failure).
            assert daemon._housekeeping._quiet.next_due() is None
            await asyncio.sleep(1.0)
            after = _drain(server)
        finally:
            daemon.request_shutdown()
            assert await asyncio.wait_for(task, WAIT_S) == 0
    assert f"nothing heard from the autopilot on {pty.path} for " in said[0]
    assert after == []
