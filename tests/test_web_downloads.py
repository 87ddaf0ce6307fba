"""The field page's downloads held to bounded memory (issue 27: a ten-day survey's
GeoJSON once took 1.5 GB): streamed as they are written, the same bytes as
`cc-daemon export`, a stalled client dropped, NetCDF's temporary file removed
however the download ends. The page's server in this process on a real TCP port,
over real journals made long with `webkit.lengthen`."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import io
import socket
import sqlite3
import tempfile
import tracemalloc
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import structlog
from aiohttp.test_utils import TestClient

from cc_daemon.cli.exportfiles import samples_csv
from cc_daemon.cli.web.policy import Limits
from cc_daemon.cli.web.server import Sources
from cc_daemon.export import geojson
from cc_daemon.store import CastRecord, FixRecord, JournalReader
from tests import webkit
from tests.webkit import WebProcess

SURVEY = 2


@pytest.fixture(scope="module")
def long_track(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """About 55,000 fixes: a GeoJSON of 13 MB."""
    db = webkit.make_journal(tmp_path_factory.mktemp("web") / "track.db")
    webkit.lengthen(db, 30)
    return db


def _samples(db: Path, copies: int) -> Path:
    """The first 6,500 samples of `db`, `copies` more times, a millisecond apart."""
    with contextlib.closing(sqlite3.connect(db)) as conn, conn:
        for k in range(1, copies + 1):
            conn.execute(
                "INSERT INTO samples (cast_id, mono_s, wall_s, clock_synced, depth_m, phase)"
                " SELECT cast_id, mono_s + ?, wall_s + ?, clock_synced, depth_m, phase"
                " FROM samples WHERE id <= (SELECT min(id) + 6500 FROM samples)",
                (k / 1000, k / 1000),
            )
    return db


@pytest.fixture(scope="module")
def many_samples(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """About 65,000 depth samples in 80 measured casts: a CSV of 7.5 MB."""
    db = webkit.make_journal(tmp_path_factory.mktemp("web") / "samples.db")
    webkit.lengthen(db, 40, fixes=False)
    return _samples(db, 14)


@pytest.fixture
def more_samples(tmp_path: Path) -> Path:
    """About 400,000 depth samples: a NetCDF of about 10 MB, more than twice what the
    kernel may hold on the page's side of one connection (its send buffer grows to
    net.ipv4.tcp_wmem's largest, 4 MB, whatever the client's window)."""
    db = webkit.make_journal(tmp_path / "samples.db")
    webkit.lengthen(db, 40, fixes=False)
    return _samples(db, 60)


@contextlib.asynccontextmanager
async def page(journal: Path, **limits: Any) -> AsyncIterator[TestClient[Any, Any]]:
    sources = Sources(socket=journal.parent / "none.sock", journal=journal)
    client: TestClient[Any, Any] = await webkit.client_for(
        sources, Limits(**limits) if limits else None
    )
    try:
        yield client
    finally:
        await client.close()


def exported(
    journal: Path, write: Callable[[JournalReader, list[CastRecord], io.StringIO], Any]
) -> bytes:
    out = io.StringIO(newline="")
    with JournalReader(journal) as reader:
        reader.select_survey(SURVEY)
        write(reader, reader.casts(), out)
    return out.getvalue().encode()


async def fetched_in_bounded_memory(
    client: TestClient[Any, Any], path: str
) -> tuple[bytes, int, str]:
    """The download's digest and size, the most memory Python held meanwhile beyond
    what it held before (tracemalloc: every thread, the server's too), and its
    Transfer-Encoding."""
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        r = await client.get(path)
        assert r.status == 200
        digest, size = hashlib.sha256(), 0
        async for chunk in r.content.iter_chunked(1 << 16):
            digest.update(chunk)
            size += len(chunk)
        peak = tracemalloc.get_traced_memory()[1] - before
    finally:
        tracemalloc.stop()
    return digest.digest() + size.to_bytes(8, "big"), peak, r.headers.get("Transfer-Encoding", "")


def fingerprint(body: bytes) -> bytes:
    return hashlib.sha256(body).digest() + len(body).to_bytes(8, "big")


@pytest.mark.timeout(240)  # tracemalloc slows every allocation: minutes on a loaded machine
async def test_a_long_surveys_geojson_is_streamed_in_bounded_memory(long_track: Path) -> None:
    body = exported(long_track, lambda r, casts, out: geojson.write(casts, r.fixes(), out))
    assert len(body) > 12_000_000
    async with page(long_track) as client:
        got, peak, sent = await fetched_in_bounded_memory(
            client, f"/download/survey/{SURVEY}.geojson"
        )
    assert got == fingerprint(body)  # the export command's file, byte for byte
    assert peak < 5_000_000, f"{peak:,} bytes held for a {len(body):,}-byte file"
    assert sent == "chunked"  # sent as it is written


@pytest.mark.timeout(240)
async def test_a_long_surveys_csv_is_streamed_in_bounded_memory(many_samples: Path) -> None:
    def write(reader: JournalReader, casts: list[CastRecord], out: io.StringIO) -> None:
        samples_csv(reader, casts, reader.samples(), out)  # as `cc-daemon export` writes it

    body = exported(many_samples, write)
    assert len(body) > 7_000_000
    async with page(many_samples) as client:
        got, peak, sent = await fetched_in_bounded_memory(client, f"/download/survey/{SURVEY}.csv")
    assert got == fingerprint(body)
    assert peak < 3_000_000, f"{peak:,} bytes held for a {len(body):,}-byte file"
    assert sent == "chunked"


@pytest.mark.parametrize("batch", [1, 2, 3, 7, 1000])
def test_the_streamed_geojson_is_the_exports_however_the_fixes_are_cut(batch: int) -> None:
    with JournalReader(webkit.make_journal(Path(tempfile.mkdtemp()) / "j.db")) as reader:
        reader.select_survey(SURVEY)
        casts, fixes = reader.casts(), reader.fixes()
    for n in (0, 1, 2, 3, len(fixes)):
        for stations in ([], casts):
            whole, cut = io.StringIO(), io.StringIO()
            geojson.write(stations, fixes[:n], whole)

            def batches(some: list[FixRecord] = fixes[:n]) -> list[list[FixRecord]]:
                return [some[i : i + batch] for i in range(0, len(some), batch)]

            count = geojson.write_batches(stations, batches, cut)
            assert cut.getvalue() == whole.getvalue()
            assert count == len(stations) + n + (n >= 2)


async def test_a_client_that_stops_reading_is_dropped(long_track: Path) -> None:
    async with page(long_track, send_stall_s=1.0) as client:
        with structlog.testing.capture_logs() as logged:
            reader, writer = await asyncio.open_connection("127.0.0.1", client.port)
            request = f"GET /download/survey/{SURVEY}.geojson HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
            writer.write(request.encode())
            began = asyncio.get_running_loop().time()
            while not any(e["event"].startswith("a download's client stopped") for e in logged):
                assert asyncio.get_running_loop().time() - began < 30
                await asyncio.sleep(0.05)
            received = b""
            with contextlib.suppress(ConnectionError):
                while chunk := await reader.read(1 << 20):
                    received += chunk
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()
    assert received.startswith(b"HTTP/1.1 200")
    assert not received.endswith(b"0\r\n\r\n")  # no last chunk: the client sees it broken
    assert len(received) < 12_000_000


async def test_netcdfs_temporary_file_is_removed_however_the_download_ends(
    long_track: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    netCDF4 = pytest.importorskip("netCDF4")
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temporary))
    async with page(long_track) as client:
        r = await client.get(f"/download/survey/{SURVEY}.nc")
        assert r.status == 200 and r.headers["Transfer-Encoding"] == "chunked"
        (tmp_path / "survey.nc").write_bytes(await r.read())
        with netCDF4.Dataset(tmp_path / "survey.nc") as nc:
            assert nc.featureType == "profile"
        assert list(temporary.iterdir()) == []
        # A client that leaves after the first bytes.
        reader, writer = await asyncio.open_connection("127.0.0.1", client.port)
        writer.write(
            f"GET /download/survey/{SURVEY}.nc HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode()
        )
        assert (await reader.read(100)).startswith(b"HTTP/1.1 200")
        writer.close()
        await writer.wait_closed()
        began = asyncio.get_running_loop().time()
        while list(temporary.iterdir()):
            assert asyncio.get_running_loop().time() - began < 30, list(temporary.iterdir())
            await asyncio.sleep(0.05)


@contextlib.contextmanager
def _slow_reader(port: int) -> Iterator[socket.socket]:
    """A client whose receive window is small (4 kB, set before it connects). The
    kernel still lets the page's send buffer grow to 4 MB (net.ipv4.tcp_wmem): only a
    larger file stays partly unsent on the page's side."""
    client = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    client.settimeout(30)
    try:
        client.connect(("127.0.0.1", port))
        yield client
    finally:
        client.close()


@pytest.mark.timeout(120)
def test_a_stop_in_the_middle_of_a_netcdf_download_removes_its_temporary_file(
    more_samples: Path, tmp_path: Path
) -> None:
    pytest.importorskip("netCDF4")
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    environ = {"TMPDIR": str(temporary)}
    with (
        WebProcess(more_samples, tmp_path / "none.sock", env=environ) as web,
        _slow_reader(web.port) as client,
    ):
        client.sendall(
            f"GET /download/survey/{SURVEY}.nc HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode()
        )
        assert client.recv(12) == b"HTTP/1.1 200"  # under way; then read no more
        # The whole file is made before its first byte is sent, and a reader whose
        # window is 4 kB holds the rest of it on the page's side (a file larger than
        # the kernel's buffers): the file is there.
        assert any(temporary.iterdir())
        web.proc.terminate()
        assert web.proc.wait(30) == 0
    assert list(temporary.iterdir()) == []
