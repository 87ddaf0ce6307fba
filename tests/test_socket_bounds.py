"""The sockets' bounds and what they keep (issue 27), on real sockets in-process.

The control socket: its caps (per user, in all, a request rate), a line too long
answered with an error, the release reason kept printable (and in the journal:
tests/test_stranded.py). The status
socket: descriptors kept in reserve, a document nested too deep refused in one
line. Where a socket may be: never in a directory another user could write.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import threading
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from cc_daemon.cli.app import main
from cc_daemon.daemon.control_server import ControlServer
from cc_daemon.daemon.status_server import StatusServer

Asked = list[tuple[str, str]]


@pytest.fixture
async def control(tmp_path: Path) -> AsyncIterator[tuple[ControlServer, Asked]]:
    """A control server whose release and home say what they were asked."""
    asked: Asked = []

    def release(peer: object, reason: str) -> tuple[bool, str]:
        asked.append(("release", reason))
        return True, f"released: {reason}"

    def home(peer: object, reason: str) -> tuple[bool, str]:
        asked.append(("home", reason))
        return True, "hauling"

    server = ControlServer(tmp_path / "control.sock", release, home)
    await server.start()
    try:
        yield server, asked
    finally:
        await server.close()


def ask(path: Path, data: bytes, timeout: float = 10.0) -> bytes:
    """Send `data` as a raw client would, then read everything the daemon answers."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(str(path))
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            sock.sendall(data)
        answer = b""
        try:
            while chunk := sock.recv(65536):
                answer += chunk
        except ConnectionResetError:
            pass
    return answer


async def test_a_line_too_long_gets_an_error_answer(
    control: tuple[ControlServer, Asked],
) -> None:
    server, asked = control
    for size in (600, 70 * 1024, 1 << 20):
        line = b"release " + b"x" * size + b"\n"
        answer = await asyncio.to_thread(ask, server.path, line)
        assert json.loads(answer) == {
            "ok": False,
            "message": "request too long: one line of at most 512 bytes",
        }, size
    assert asked == []  # nothing was released on a cut line


async def test_a_release_reason_is_kept_printable_and_bounded(
    control: tuple[ControlServer, Asked],
) -> None:
    server, asked = control
    line = "release probe\x1b[2J on\r deck\x00 \u202eevil\u200b ok\n".encode()
    answer = await asyncio.to_thread(ask, server.path, line)
    assert json.loads(answer)["ok"] is True
    assert asked == [("release", "probe\\x1b[2J on\\x0d deck\\x00 \\u202eevil\\u200b ok")]
    long = "release " + "é" * 250 + "\n"  # 508 bytes: within the line, past the reason
    await asyncio.to_thread(ask, server.path, long.encode())
    assert asked[-1] == ("release", "é" * 199 + "…")


async def test_one_user_holds_at_most_four_connections(
    control: tuple[ControlServer, Asked],
) -> None:
    server, asked = control
    held = [socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) for _ in range(4)]
    try:
        for sock in held:
            sock.connect(str(server.path))  # each waits to send its line
        await asyncio.sleep(0.1)
        answer = json.loads(await asyncio.to_thread(ask, server.path, b"home\n"))
        assert answer["ok"] is False and answer["message"].startswith("busy (4 connections")
    finally:
        for sock in held:
            sock.close()
    for _ in range(200):  # their places are given back as they close
        answer = json.loads(await asyncio.to_thread(ask, server.path, b"home\n"))
        if answer["ok"]:
            break
        await asyncio.sleep(0.05)
    assert answer == {"ok": True, "message": "hauling"} and asked == [("home", "operator request")]


async def test_one_user_makes_at_most_a_burst_of_five_requests(
    control: tuple[ControlServer, Asked],
) -> None:
    server, asked = control
    answers = [json.loads(await asyncio.to_thread(ask, server.path, b"home\n")) for _ in range(6)]
    assert [a["ok"] for a in answers] == [True] * 5 + [False]
    assert answers[-1]["message"] == (
        "busy (more than 10 connections a minute of this user on the control socket): try again"
    )
    assert len(asked) == 5


async def test_the_status_socket_keeps_the_daemon_s_descriptors(tmp_path: Path) -> None:
    from cc_daemon.daemon.admission import RESERVE, DescriptorBudget

    # As if the process had 10 descriptors left above its reserve.
    budget = DescriptorBudget(count=lambda: 1000 - RESERVE - 10, limit=lambda: 1000)
    server = StatusServer(
        tmp_path / "s.sock", lambda: {"ok": 1}, budget=budget, client_timeout_s=30
    )
    await server.start()
    held: list[socket.socket] = []
    try:
        for _ in range(3):
            # Ten clients (the listen backlog holds them) that send garbage and wait:
            # each answered one lingers, holding its descriptor until it closes.
            for _ in range(10):
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                held.append(sock)
                sock.connect(str(server.path))
                sock.send(b"garbage")
            for _ in range(200):
                await asyncio.sleep(0.02)
                if server.served + server.refused == len(held):
                    break
        assert (server.served, server.refused, budget.held) == (10, 20, 10)
        for sock in held[10:]:  # closed unanswered: nothing to read
            sock.settimeout(10)
            with contextlib.suppress(ConnectionResetError):
                assert sock.recv(100) == b""
    finally:
        for sock in held:
            sock.close()
        await server.close()
    assert budget.held == 0


def serve_raw(path: Path, data: bytes) -> threading.Thread:
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(str(path))
    server.listen()

    def answer() -> None:
        with server:
            conn, _ = server.accept()
            with conn, contextlib.suppress(OSError):  # the test's own unblocking client
                conn.sendall(data)

    thread = threading.Thread(target=answer)
    thread.start()
    return thread


@pytest.mark.parametrize("depth", [100, 10_000])
def test_a_document_nested_too_deep_is_one_line(
    tmp_path: Path, depth: int, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / f"deep{depth}.sock"
    thread = serve_raw(path, b'{"a":' + b"[" * depth + b"]" * depth + b"}\n")
    code = main(["status", "--socket", str(path)])
    thread.join()
    err = capsys.readouterr().err
    assert code == 1 and err == f"cc-daemon status: {path}: the answer is not a status document\n"


def test_a_socket_in_a_directory_every_user_may_write_is_never_asked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)  # as /tmp
    path = shared / "status.sock"
    thread = serve_raw(path, b'{"daemon": {}}\n')
    try:
        assert main(["status", "--socket", str(path)]) == 1
        err = capsys.readouterr().err
        assert err == (
            f"cc-daemon status: refusing {path}: {shared} may be written by every user,"
            " so anyone could answer there\n"
        )
        assert main(["release", "--reason", "x", "--socket", str(path)]) == 1
        assert "may be written by every user" in capsys.readouterr().err
    finally:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as unblock:
            unblock.connect(str(path))
        thread.join()


@pytest.mark.parametrize(
    ("mode", "owner", "problem"),
    [
        (0o755, None, None),
        (0o700, None, None),
        (0o775, None, None),  # the group's members are trusted as the group's
        (0o1777, None, "{d} may be written by every user"),
        (0o777, None, "{d} may be written by every user"),
        (0o755, 54321, "{d} belongs to another user (uid 54321)"),
    ],
)
def test_where_another_user_could_bind_a_socket(
    tmp_path: Path, mode: int, owner: int | None, problem: str | None
) -> None:
    from cc_daemon.config.statuspaths import shared_directory

    directory = tmp_path / "d"
    directory.mkdir()
    directory.chmod(mode)
    if owner is not None:
        if os.geteuid() != 0:
            pytest.skip("needs root to give a directory to another uid")
        os.chown(directory, owner, -1)
    expected = problem.format(d=directory) if problem else None
    assert shared_directory(directory / "s.sock") == expected
    # Below a sticky world-writable directory, one's own directory is safe; below a
    # world-writable one that is not sticky, nothing is (it can be renamed away).
    if mode == 0o1777 and owner is None:
        (directory / "mine").mkdir(mode=0o755)
        assert shared_directory(directory / "mine" / "s.sock") is None
    if mode == 0o777 and owner is None:
        (directory / "mine").mkdir(mode=0o755)
        assert shared_directory(directory / "mine" / "s.sock") == expected


def test_status_path_in_tmp_is_refused_at_start(tmp_path: Path) -> None:
    from tests.test_preflight import PREFIX, run_daemon

    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    config = tmp_path / "c.toml"
    config.write_text(f'[status]\npath = "{shared / "s.sock"}"\n')
    done = run_daemon(
        tmp_path,
        "--config", str(config),
        "--db", str(tmp_path / "journal.db"),
        "--port", str(tmp_path / "ttyNotThere"),
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr == (
        f'{PREFIX}status.path = "{shared / "s.sock"}" (from {config}): {shared} may be written'
        " by every user, so anyone could answer in the daemon's place; choose a directory"
        " only the daemon's user may write, or leave it unset\n"
    )
    assert not (tmp_path / "journal.db").exists()


def test_a_journal_in_a_shared_directory_has_its_sockets_in_the_private_one(
    tmp_path: Path,
) -> None:
    from cc_daemon.config.statuspaths import SERVICE_SOCKET, client_socket_paths, hand_socket_path

    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o1777)
    journal = shared / "bench-test.db"
    env = {"XDG_RUNTIME_DIR": "/run/user/1000"}
    hand = hand_socket_path(journal, env)
    assert hand is not None and hand.parent == Path("/run/user/1000/cc-daemon")
    assert hand.name.startswith("bench-test.db-") and hand.name.endswith(".status.sock")
    # One socket per journal, the same for the daemon and the tools.
    assert hand_socket_path(shared / "other.db", env) != hand
    assert client_socket_paths(None, env, journal) == [hand, SERVICE_SOCKET]
    # No runtime directory: $TMPDIR/cc-daemon-UID, made 0700 by the daemon.
    hand = hand_socket_path(journal, {"TMPDIR": "/var/tmp"})
    assert hand is not None and hand.parent == Path(f"/var/tmp/cc-daemon-{os.geteuid()}")
    # A journal in a directory of one's own: beside it, as before.
    (tmp_path / "own").mkdir()
    assert hand_socket_path(tmp_path / "own" / "j.db", env) == tmp_path / "own" / "j.db.status.sock"


def test_refusals_are_said_at_once_then_once_a_minute_with_their_count() -> None:
    import structlog

    from cc_daemon.daemon.socket_listener import Refusals

    now = [100.0]
    refusals = Refusals("control", clock=lambda: now[0])
    with structlog.testing.capture_logs() as logs:
        for _ in range(1000):  # a flood within the minute: one line, then counted
            refusals.add(1001, "4 connections of this user already")
            now[0] += 0.01
        assert [e["event"] for e in logs] == ["control socket: connection refused"]
        now[0] = 161.0
        refusals.add(1001, "4 connections of this user already")  # the minute is over
        assert logs[-1]["event"] == "control socket: connections refused"
        assert (logs[-1]["count"], logs[-1]["uid"]) == (1000, 1001)
        refusals.add(1002, "not authorised")
        refusals.flush()  # the socket closes: what is held is said
    assert (logs[-1]["uid"], logs[-1]["count"]) == (1002, 1) and len(logs) == 3
    assert refusals.total == 1002
