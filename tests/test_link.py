"""The serial link over a real pty: reads, writes, loss, reopen, backoff."""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Callable
from pathlib import Path

import pytest

from cc_daemon.drivers.link import SerialLink
from cc_daemon.sim.pty import PtyPair
from tests.waitkit import until


def test_backoff_grows_to_the_cap_with_bounded_jitter() -> None:
    low = SerialLink("x", on_data=lambda _: None, jitter=lambda: 0.0)
    high = SerialLink("x", on_data=lambda _: None, jitter=lambda: 1.0)
    ceilings = [high.backoff_delay(n) for n in range(1, 10)]
    assert ceilings == pytest.approx([0.2, 0.4, 0.8, 1.6, 3.2, 5.0, 5.0, 5.0, 5.0])
    assert [low.backoff_delay(n) for n in (1, 9)] == pytest.approx([0.15, 3.75])


async def _read_master(pty: PtyPair, size: int) -> bytes:
    """The next `size` bytes the link wrote, as soon as they are there."""
    got = bytearray()

    def read() -> bool:
        with contextlib.suppress(BlockingIOError):
            got.extend(os.read(pty.master_fd, size - len(got)))
        return len(got) >= size

    await until(read, f"{size} bytes written by the link")
    return bytes(got)


async def test_reads_writes_survives_an_unplug_and_reopens(tmp_path: Path) -> None:
    pty = PtyPair(tmp_path / "tty")
    received = bytearray()
    states: list[tuple[bool, str]] = []
    link = SerialLink(
        str(pty.path),
        on_data=received.extend,
        on_state=lambda up, why: states.append((up, why)),
        reconnect_initial_s=0.05,
        reconnect_max_s=0.2,
    )
    task = asyncio.create_task(link.run())
    try:
        await until(lambda: link.up)
        assert link.write(b"RO\x00H\x00\xe9")
        assert await _read_master(pty, 6) == b"RO\x00H\x00\xe9"
        os.write(pty.master_fd, b"PS\x00H\x00\xeb")
        await until(lambda: bytes(received) == b"PS\x00H\x00\xeb")

        pty.unplug()
        await until(lambda: not link.up)
        assert link.write(b"RO\x00H\x00\xe9") is False  # nothing is queued while down
        assert link.frames_dropped == 1
        # Several failed reopen attempts: the path is gone.
        await until(lambda: link.waiting.attempts >= 3)
        pty.replug()
        await until(lambda: link.up)
        os.write(pty.master_fd, b"PS\x00I\x00\xec")
        await until(lambda: bytes(received).endswith(b"PS\x00I\x00\xec"))
        # The frame written while down never arrives after the reopen: the first
        # bytes on the new line are the next frame written.
        assert link.write(b"RP\x00I\x00\x00\x00\xeb")
        assert await _read_master(pty, 8) == b"RP\x00I\x00\x00\x00\xeb"
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        pty.close()
    assert [up for up, _ in states] == [True, False, True]
    assert link.opens == 2


async def test_a_handler_exception_does_not_stop_reading(tmp_path: Path) -> None:
    pty = PtyPair(tmp_path / "tty")
    calls: list[bytes] = []

    def handler(data: bytes) -> None:
        calls.append(data)
        if len(calls) == 1:
            raise RuntimeError("handler bug")

    link = SerialLink(str(pty.path), on_data=handler)
    task = asyncio.create_task(link.run())
    try:
        await until(lambda: link.up)
        os.write(pty.master_fd, b"first")
        await until(lambda: len(calls) == 1)
        os.write(pty.master_fd, b"second")
        await until(lambda: len(calls) == 2)
        assert link.up
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        pty.close()


class _FakeTransport(asyncio.Transport):
    def __init__(self) -> None:
        super().__init__()
        self.closed = False

    def is_closing(self) -> bool:
        return self.closed

    def close(self) -> None:
        self.closed = True

    def write(self, data: bytes | bytearray | memoryview) -> None:
        pass


class _RecordingLink(SerialLink):
    """Records the reopen attempt numbers instead of sleeping them."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__("fake", on_data=lambda _: None, **kwargs)  # type: ignore[arg-type]
        self.attempts: list[int] = []

    def backoff_delay(self, failures: int) -> float:
        self.attempts.append(failures)
        return 0.001


def _fake_port(monkeypatch: pytest.MonkeyPatch, up_for_s: float, failures: list[Exception]) -> None:
    async def create(loop: asyncio.AbstractEventLoop, factory: object, *args: object, **kw: object):  # type: ignore[no-untyped-def]
        if failures:
            raise failures.pop(0)
        protocol = factory()  # type: ignore[operator]
        transport = _FakeTransport()
        loop.call_later(up_for_s, protocol.connection_lost, OSError(5, "Input/output error"))
        return transport, protocol

    monkeypatch.setattr("cc_daemon.drivers.link.fdserial.create_serial_connection", create)


async def _run_until(link: SerialLink, done: Callable[[], bool]) -> None:
    """Run the link until `done()` holds (however long the machine takes), then stop it."""
    task = asyncio.create_task(link.run())
    try:
        await until(done)
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def test_a_flapping_port_keeps_backing_off(monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_port(monkeypatch, up_for_s=0.0, failures=[])
    link = _RecordingLink(reconnect_initial_s=0.2, reconnect_max_s=5.0)
    await _run_until(link, lambda: len(link.attempts) >= 5)
    assert link.attempts[:5] == [1, 2, 3, 4, 5]


async def test_a_port_that_stayed_up_starts_again_from_the_shortest_delay(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _fake_port(monkeypatch, up_for_s=0.03, failures=[])
    link = _RecordingLink(reconnect_initial_s=0.001, reconnect_max_s=0.01)
    await _run_until(link, lambda: len(link.attempts) >= 3)
    assert set(link.attempts) == {1}


async def test_any_error_opening_the_port_is_retried(monkeypatch: pytest.MonkeyPatch) -> None:
    import termios

    _fake_port(
        monkeypatch,
        up_for_s=10.0,
        failures=[termios.error(5, "Input/output error"), RuntimeError("odd driver")],
    )
    link = _RecordingLink()
    await _run_until(link, lambda: link.opens == 1)
    assert link.attempts == [1, 2]


async def test_a_port_locked_by_another_process_names_the_holder(tmp_path: Path) -> None:
    import subprocess
    import sys

    from cc_daemon.ground.waiting import WaitReport

    pty = PtyPair(tmp_path / "tty")
    # Another process holds the port with the lock pyserial takes (a second daemon).
    holder = subprocess.Popen(  # noqa: ASYNC220 - started before the loop matters
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys, time; fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY);"
            " fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB); print('locked', flush=True);"
            " time.sleep(30)",
            str(pty.path),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    said: list[str] = []
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "locked\n"
        link = SerialLink(
            str(pty.path),
            on_data=lambda _: None,
            reconnect_initial_s=0.02,
            reconnect_max_s=0.05,
            on_waiting=said.append,
            wait_report=WaitReport(first_s=0.1, max_s=0.1),
        )
        task = asyncio.create_task(link.run())
        try:
            await until(lambda: len(said) >= 2)
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
    finally:
        holder.kill()
        holder.wait()
        if holder.stdout is not None:
            holder.stdout.close()
        pty.close()
    assert f"(held by pid {holder.pid} (python" in said[0], said
    assert not link.up
