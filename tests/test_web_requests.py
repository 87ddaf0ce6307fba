"""The field page held against crafted requests (issue 27): parameters that once gave
500s, headers it read wrong, HEAD, a `Host` from elsewhere (DNS rebinding), what a
404 says, and a flood of wrong passwords. The page's server, in this process, on a
real TCP port (aiohttp's test server), over a real journal and status socket."""

from __future__ import annotations

import asyncio
import base64
import threading
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import structlog
from aiohttp.test_utils import TestClient

from cc_daemon.cli.web import auth
from cc_daemon.cli.web.policy import Limits
from cc_daemon.cli.web.server import Sources
from cc_daemon.daemon.status_server import StatusServer
from cc_daemon.store.reader import JournalReader
from tests import webkit

SECURITY = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}
PASSWORD = "sea-spray 7"


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return webkit.make_journal(tmp_path_factory.mktemp("web") / "survey.db")


@pytest.fixture(scope="module")
def setting() -> str:
    return auth.hash_password(PASSWORD)


@pytest.fixture
async def socket(tmp_path: Path) -> AsyncIterator[Path]:
    server = StatusServer(tmp_path / "status.sock", webkit.status)
    await server.start()
    yield server.path
    await server.close()


async def client_for(sources: Sources) -> TestClient[Any, Any]:
    client: TestClient[Any, Any] = await webkit.client_for(sources)
    return client


@pytest.fixture
async def client(journal: Path, socket: Path) -> AsyncIterator[TestClient[Any, Any]]:
    c = await client_for(Sources(socket=socket, journal=journal))
    yield c
    await c.close()


@pytest.fixture
async def guarded(journal: Path, socket: Path, setting: str) -> AsyncIterator[TestClient[Any, Any]]:
    c = await client_for(Sources(socket=socket, journal=journal, password_hash=setting))
    yield c
    await c.close()


def basic(user: str, password: str, encoding: str = "utf-8", scheme: str = "Basic") -> str:
    return f"{scheme} {base64.b64encode(f'{user}:{password}'.encode(encoding)).decode()}"


def carries_the_headers(r: aiohttp.ClientResponse) -> None:
    for name, value in SECURITY.items():
        assert r.headers.get(name) == value, name


@pytest.mark.parametrize(
    "path",
    [
        "/api/casts/9999999999999999999/profile",  # past SQLite's integer: OverflowError
        "/api/events?survey=%C2%B2",  # '²'.isdigit() is true; int() refuses it
        "/api/events?survey=" + "7" * 5000,  # past int()'s 4,300 digits
        "/api/surveys/" + "7" * 5000 + "/casts",
        "/download/survey/99999999999999999999.csv",
    ],
)
async def test_crafted_numbers_are_a_400_with_the_headers_and_no_traceback(
    client: TestClient[Any, Any], path: str
) -> None:
    with structlog.testing.capture_logs() as logged:
        r = await client.get(path)
        assert r.status == 400
        carries_the_headers(r)
        message = (await r.json())["error"]
    assert "number" in message and len(message) < 200 and "\n" not in message
    assert logged == []


async def test_a_non_utf8_authorization_header_is_a_400_not_a_500(
    guarded: TestClient[Any, Any],
) -> None:
    with structlog.testing.capture_logs() as logged:
        reader, writer = await asyncio.open_connection("127.0.0.1", guarded.port)
        writer.write(
            b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n"
            b"Authorization: Basic \xff\xfe\xc3==\r\n\r\n"
        )
        answer = await reader.read()
        writer.close()
        await writer.wait_closed()
    head = answer.partition(b"\r\n\r\n")[0].decode().lower()
    assert head.startswith("http/1.1 400")
    for name, value in SECURITY.items():
        assert f"{name.lower()}: {value.lower()}" in head
    assert logged == []


async def test_a_status_document_nested_10000_deep_is_said_unreadable(
    journal: Path, tmp_path: Path
) -> None:
    async def deep(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(b'{"a":' * 10_000 + b"1" + b"}" * 10_000)
        await writer.drain()
        writer.close()

    path = tmp_path / "deep.sock"
    server = await asyncio.start_unix_server(deep, path)
    c = await client_for(Sources(socket=path, journal=journal))
    try:
        with structlog.testing.capture_logs() as logged:
            r = await c.get("/api/status")
            assert r.status == 200  # the page works; the daemon's answer is what is wrong
            carries_the_headers(r)
            doc = await r.json()
        assert doc["reachable"] is False and "not a status document" in doc["reason"]
        assert logged == []
    finally:
        await c.close()
        server.close()
        await server.wait_closed()


async def test_the_auth_scheme_is_matched_in_any_case(guarded: TestClient[Any, Any]) -> None:
    for scheme in ("basic", "BASIC", "bAsIc"):
        r = await guarded.get(
            "/api/status", headers={"Authorization": basic("crew", PASSWORD, scheme=scheme)}
        )
        assert r.status == 200, scheme


async def test_a_latin1_user_name_and_password_verify(journal: Path, socket: Path) -> None:
    setting = auth.hash_password("mañana")
    c = await client_for(Sources(socket=socket, journal=journal, password_hash=setting))
    try:
        for encoding in ("latin-1", "utf-8"):
            header = basic("Jürgen", "mañana", encoding)
            assert (await c.get("/api/status", headers={"Authorization": header})).status == 200
        wrong = basic("Jürgen", "manana", "latin-1")
        assert (await c.get("/api/status", headers={"Authorization": wrong})).status == 401
    finally:
        await c.close()


async def test_head_of_a_download_is_refused_and_builds_nothing(
    client: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    opened: list[object] = []
    real = JournalReader.select_survey

    def counting(self: JournalReader, choice: str | int) -> Any:
        opened.append(choice)
        return real(self, choice)

    monkeypatch.setattr(JournalReader, "select_survey", counting)
    for fmt in ("csv", "geojson", "nc"):
        r = await client.head(f"/download/survey/2.{fmt}")
        assert r.status == 405 and r.headers["Allow"] == "GET"
        carries_the_headers(r)
    assert opened == []
    assert (await client.get("/download/survey/2.csv")).status == 200 and opened == [2]


async def test_no_answer_names_the_server_software(client: TestClient[Any, Any]) -> None:
    for path in ("/", "/api/status", "/nowhere", "/api/events?survey=x"):
        r = await client.get(path)
        assert r.headers["Server"] == "cc-daemon", path
        carries_the_headers(r)


@pytest.mark.parametrize(
    "path",
    [
        "/api/surveys/99/casts",
        "/api/casts/9999/profile",
        "/api/events?survey=99",
        "/download/survey/99.csv",
        "/download/survey/99.geojson",
        "/nowhere",
    ],
)
async def test_a_404_never_names_the_journal_or_any_path(
    client: TestClient[Any, Any], journal: Path, path: str
) -> None:
    r = await client.get(path)
    assert r.status == 404
    carries_the_headers(r)
    text = await r.text()
    assert str(journal.parent) not in text and journal.name not in text
    assert "/tmp" not in text and "/var" not in text


async def test_a_host_from_elsewhere_is_refused_a_421(client: TestClient[Any, Any]) -> None:
    # A DNS-rebinding page names its own host; the default page has no password.
    for host in ("rebind.attacker.example", "rebind.attacker.example:8080", "[bad", "b\u00e9"):
        r = await client.get("/api/status", headers={"Host": host})
        assert r.status == 421, host
        carries_the_headers(r)
        assert "reachable" not in await r.text()
    for host in ("127.0.0.1:8080", "localhost:8080", "LOCALHOST", "[::1]:8080", "192.168.4.1"):
        assert (await client.get("/api/status", headers={"Host": host})).status == 200, host


async def test_the_names_in_web_hosts_are_answered(journal: Path, socket: Path) -> None:
    names = frozenset({"localhost", "boat.example.org"})
    c = await client_for(Sources(socket=socket, journal=journal, hosts=names))
    try:
        for host in ("boat.example.org", "Boat.Example.Org.:80"):
            assert (await c.get("/api/status", headers={"Host": host})).status == 200, host
        assert (await c.get("/api/status", headers={"Host": "other.example.org"})).status == 421
    finally:
        await c.close()


async def test_wrong_passwords_run_off_the_loop_and_each_client_is_limited(
    guarded: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    checks: list[bool] = []  # on the event loop's thread?
    real = auth.verify_password

    def watched(password: str, setting: str) -> bool:
        checks.append(threading.current_thread() is threading.main_thread())
        return real(password, setting)

    monkeypatch.setattr(auth, "verify_password", watched)
    good = {"Authorization": basic("crew", PASSWORD)}
    assert (await guarded.get("/api/status", headers=good)).status == 200
    flood = await asyncio.gather(
        *(guarded.get("/api/status", headers={"Authorization": basic("x", f"guess {n}")})
          for n in range(40))
    )  # fmt: skip
    statuses = [r.status for r in flood]
    burst = Limits().password_burst
    assert statuses.count(401) <= burst and statuses.count(429) >= 40 - burst
    for r in flood:
        carries_the_headers(r)
        if r.status == 429:
            assert int(r.headers["Retry-After"]) >= 1
    assert len(checks) <= 1 + burst and not any(checks)
    # The logged-in page is not held up, nor the right password from elsewhere.
    assert (await guarded.get("/api/status", headers=good)).status == 200
    elsewhere = aiohttp.TCPConnector(local_addr=("127.0.0.2", 0))
    async with aiohttp.ClientSession(connector=elsewhere) as session:
        header = {"Authorization": basic("deck", PASSWORD)}
        async with session.get(guarded.make_url("/api/status"), headers=header) as r:
            assert r.status == 200
