"""The field page held against clients that take connections and give nothing back
(issue 27): idle and trickling connections, more of them than it has descriptors,
one address taking them all, and a flood of requests it cannot parse. Real
`cc-daemon web` subprocesses (or its server in this process) on 127.0.0.1, real
sockets from several loopback addresses (127.0.0.2 and up: Linux answers every
127/8 address)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from cc_daemon.cli.web.policy import Limits
from cc_daemon.cli.web.server import Sources
from tests import webkit
from tests.webkit import WebProcess, deadline_poll, get

SECURITY = ("content-security-policy", "x-content-type-options", "referrer-policy")


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return webkit.make_journal(tmp_path_factory.mktemp("web") / "survey.db")


@contextlib.contextmanager
def idle(port: int, count: int, sources: list[str]) -> Iterator[list[socket.socket]]:
    """`count` connections that send nothing, spread over `sources`, begun without
    waiting for the page to accept them (it may not); all closed at the end."""
    made: list[socket.socket] = []
    try:
        for n in range(count):
            sock = socket.socket()
            made.append(sock)
            sock.bind((sources[n % len(sources)], 0))
            sock.setblocking(False)
            sock.connect_ex(("127.0.0.1", port))
        yield made
    finally:
        for sock in made:
            sock.close()


async def close_all(
    reads: list[asyncio.Future[bytes]],
    connections: list[tuple[asyncio.StreamReader, asyncio.StreamWriter]],
) -> None:
    for task in reads:
        task.cancel()
    for _, writer in connections:
        writer.close()
    await asyncio.gather(*reads, return_exceptions=True)


def closed_by_peer(sock: socket.socket) -> bool:
    """Whether the other end has closed (EOF or reset), without blocking."""
    if not select.select([sock], [], [], 0)[0]:
        return False
    try:
        return sock.recv(65536) == b""
    except ConnectionResetError:
        return True
    except BlockingIOError:
        return False


@pytest.mark.timeout(120)
def test_idle_connections_past_its_descriptors_leave_the_page_answering_and_the_log_quiet(
    journal: Path, tmp_path: Path
) -> None:
    # 400 connections that send nothing, against 160 descriptors: on the old page,
    # the accept loop failed with EMFILE for ever (a traceback each time) and no
    # request was answered again.
    with WebProcess(journal, tmp_path / "none.sock", nofile=160) as web:
        addresses = [f"127.0.0.{n}" for n in range(2, 22)]  # 20 each: within one's share
        with idle(web.port, 400, addresses):
            status, _, body = get(web.url + "api/status")
            assert status == 200 and json.loads(body)["reachable"] is False
            assert get(web.url + "api/surveys")[0] == 200
        log = web.log()
    assert sum(len(line) for line in log) < 4096, log
    assert not any(b"Traceback" in line or b"exception" in line for line in log), log
    said = [json.loads(line)["event"] for line in log]
    assert len(said) == len(set(said)) <= 3, said  # each at most once a minute


@pytest.mark.timeout(120)
def test_silent_trickling_and_idle_keep_alive_connections_are_closed(
    journal: Path, tmp_path: Path
) -> None:
    limits = Limits()
    with WebProcess(journal, tmp_path / "none.sock") as web:
        silent = socket.create_connection(("127.0.0.1", web.port))
        trickle = socket.create_connection(("127.0.0.1", web.port))
        kept = socket.create_connection(("127.0.0.1", web.port))
        stop = threading.Event()

        def drip() -> None:  # a header a byte at a time, never ending
            head = b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 10_000
            for byte in head:
                if stop.wait(0.5):
                    return
                try:
                    trickle.send(bytes([byte]))
                except OSError:
                    return

        dripping = threading.Thread(target=drip)
        dripping.start()
        try:
            kept.sendall(b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            answer = b""
            while b"\r\n\r\n" not in answer:
                answer += kept.recv(65536)
            assert answer.startswith(b"HTTP/1.1 200")
            began = time.monotonic()
            for sock in (silent, trickle, kept):
                sock.setblocking(False)
            deadline_poll(
                lambda: all(closed_by_peer(s) for s in (silent, trickle, kept)),
                "the silent, trickling and idle connections closed by the page",
                limits.idle_timeout_s + 60,
            )
            # Closed by the page's timeouts, not by anything sooner.
            assert time.monotonic() - began >= limits.header_timeout_s - 1
        finally:
            stop.set()
            dripping.join()
            for sock in (silent, trickle, kept):
                sock.close()


async def test_one_address_gets_its_share_of_the_connections_and_no_more(
    journal: Path, tmp_path: Path
) -> None:
    share = Limits().per_client
    sources = Sources(socket=tmp_path / "none.sock", journal=journal)
    async with webkit.served(sources) as url:
        port = int(url.rsplit(":", 1)[1].strip("/"))
        held = []
        for _ in range(share + 8):
            held.append(
                await asyncio.open_connection("127.0.0.1", port, local_addr=("127.0.0.2", 0))
            )
        try:
            ended = [asyncio.ensure_future(reader.read()) for reader, _ in held]
            began = time.monotonic()
            while sum(task.done() for task in ended) < 8:
                assert time.monotonic() - began < 30, "8 connections refused at once"
                await asyncio.sleep(0.05)
            # The rest of the page is untouched: another address is answered.
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(
                b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
            )
            assert (await reader.read()).startswith(b"HTTP/1.1 200")
            writer.close()
            await writer.wait_closed()
        finally:
            await close_all(ended, held)


async def test_a_full_page_makes_room_for_an_address_below_its_share(
    journal: Path, tmp_path: Path
) -> None:
    sources = Sources(socket=tmp_path / "none.sock", journal=journal)
    async with webkit.served(sources, limits=Limits(connections=20)) as url:
        port = int(url.rsplit(":", 1)[1].strip("/"))

        async def connect(source: str) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
            return await asyncio.open_connection("127.0.0.1", port, local_addr=(source, 0))

        heavy = [await connect("127.0.0.2") for _ in range(20)]  # the page is full
        ended = [asyncio.ensure_future(reader.read()) for reader, _ in heavy]
        try:
            # More from the address that holds everything: refused at once.
            reader, writer = await connect("127.0.0.2")
            with contextlib.suppress(ConnectionError):
                assert await asyncio.wait_for(reader.read(), 30) == b""
            writer.close()
            assert not any(task.done() for task in ended)
            # Another address: answered, in the place of one of those.
            reader, writer = await connect("127.0.0.3")
            writer.write(
                b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
            )
            assert (await asyncio.wait_for(reader.read(), 30)).startswith(b"HTTP/1.1 200")
            writer.close()
            await asyncio.wait_for(asyncio.wait(ended, return_when=asyncio.FIRST_COMPLETED), 30)
            assert sum(task.done() for task in ended) == 1
        finally:
            await close_all(ended, heavy)


@pytest.mark.timeout(120)
def test_a_flood_of_unparsable_requests_is_refused_with_its_headers_in_one_log_line(
    journal: Path, tmp_path: Path
) -> None:
    with WebProcess(journal, tmp_path / "none.sock") as web:
        for n in range(50):
            with socket.create_connection(("127.0.0.1", web.port), timeout=30) as sock:
                sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\nno colon here %d\r\n\r\n" % n)
                answer = b""
                while chunk := sock.recv(65536):
                    answer += chunk
            head, _, body = answer.partition(b"\r\n\r\n")
            assert head.startswith(b"HTTP/1.") and b" 400 " in head.split(b"\r\n")[0]
            for name in SECURITY:
                assert name.encode() in head.lower()
            assert json.loads(body) == {"error": "a malformed HTTP request"}
        assert get(web.url + "api/status")[0] == 200
        log = web.log()
    assert len(log) == 1 and b"Traceback" not in log[0], log


# Out of descriptors with the cap set past them (what a descriptor taken elsewhere,
# by the journal or a thread, would do): the accept loop must neither spin nor log
# each failure, and must keep answering.
_NO_SPIN = """
import asyncio, json, resource, sys
from pathlib import Path
from cc_daemon.cli.web import listener, weblog
from cc_daemon.cli.web.policy import Limits
from cc_daemon.cli.web.server import Sources, serve

weblog.configure("json", "info")
failures = 0
real = listener.Connections.make_room

def counting(self):
    global failures
    failures += 1
    return real(self)

async def main():
    import os
    loop = asyncio.get_running_loop()
    loop.set_exception_handler(weblog.loop_error)
    opened = len(os.listdir("/proc/self/fd"))
    resource.setrlimit(resource.RLIMIT_NOFILE, (opened + 40, opened + 40))
    listener.Connections.make_room = counting
    def ready(address, *rest):
        print(address, flush=True)
    sources = Sources(socket=Path(sys.argv[1]), journal=Path(sys.argv[2]))
    task = asyncio.create_task(serve(sources, "127.0.0.1:0", ready=ready,
                                     limits=Limits(connections=1000, reserve_fds=0)))
    await loop.run_in_executor(None, sys.stdin.readline)
    print(json.dumps({"make_room": failures}), flush=True)
    task.cancel()

asyncio.run(main())
"""


@pytest.mark.timeout(120)
def test_out_of_descriptors_the_page_makes_room_without_spinning_or_flooding_the_log(
    journal: Path, tmp_path: Path
) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", _NO_SPIN, str(tmp_path / "none.sock"), str(journal)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        cwd=webkit.REPO, text=True,
    )  # fmt: skip
    try:
        assert proc.stdin is not None and proc.stdout is not None
        address = proc.stdout.readline().strip()
        port = int(address.rsplit(":", 1)[1])
        addresses = [f"127.0.0.{n}" for n in range(2, 12)]
        with idle(port, 200, addresses) as made:
            deadline_poll(
                lambda: get(f"http://{address}/api/status", timeout=5)[0] == 200,
                "the page answering past its descriptors",
            )
            assert len(made) == 200
        proc.stdin.write("\n")
        proc.stdin.flush()
        counts = json.loads(proc.stdout.readline())
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()
    # At most one try per connection made room for: no retrying in a loop.
    assert 0 < counts["make_room"] <= 200 + 10
    lines = err.splitlines()
    assert len(lines) <= 3 and "Traceback" not in err, err
    said = {json.loads(line)["event"] for line in lines}
    assert "cannot accept a connection" in said
    assert "Too many open files" in err  # EMFILE, said in the line


def test_the_event_loops_own_errors_are_logged_once_a_minute(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from cc_daemon.cli.web import weblog

    weblog.configure("json", "info")
    loop = asyncio.new_event_loop()
    try:
        for _ in range(1000):  # what asyncio's accept loop said for each try, out of descriptors
            context = {
                "message": "socket.accept() out of system resource",
                "exception": OSError(24, "Too many open files"),
            }
            weblog.loop_error(loop, context)
    finally:
        loop.close()
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1, lines
    said = json.loads(lines[0])
    assert said["event"] == "asyncio: socket.accept() out of system resource"
    assert said["error"] == "OSError" and "Too many open files" in said["exception"]
