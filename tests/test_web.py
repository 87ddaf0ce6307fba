"""`cc-daemon web`: the field page's server against a real journal and a real status
socket, through aiohttp's test client (in process, on a real TCP port)."""

from __future__ import annotations

import base64
import csv
import io
import json
import subprocess
import sys
import zipfile
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from cc_daemon.cli.web import auth
from cc_daemon.cli.web.server import Sources
from cc_daemon.daemon.status_server import StatusServer
from cc_daemon.store import JournalReader
from tests import webkit
from tests.daemonkit import REPO


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return webkit.make_journal(tmp_path_factory.mktemp("web") / "survey.db")


@pytest.fixture
async def socket(tmp_path: Path) -> AsyncIterator[tuple[Path, dict[str, Any]]]:
    doc = webkit.status()
    server = StatusServer(tmp_path / "status.sock", lambda: doc)
    await server.start()
    yield server.path, doc
    await server.close()


async def client_for(sources: Sources) -> TestClient[Any, Any]:
    client: TestClient[Any, Any] = await webkit.client_for(sources)
    return client


@pytest.fixture
async def client(
    journal: Path, socket: tuple[Path, dict[str, Any]]
) -> AsyncIterator[TestClient[Any, Any]]:
    c = await client_for(Sources(socket=socket[0], journal=journal))
    yield c
    await c.close()


async def test_status_is_the_daemons_document_every_section_of_it(
    client: TestClient[Any, Any],
) -> None:
    r = await client.get("/api/status")
    assert r.status == 200
    doc = await r.json()
    assert doc["reachable"] is True
    for name, section in webkit.STATUS.items():
        assert doc[name] == section  # tide_gauge too: unknown sections pass through


async def test_a_daemon_not_running_is_said_not_hidden(journal: Path, tmp_path: Path) -> None:
    c = await client_for(Sources(socket=tmp_path / "none.sock", journal=journal))
    try:
        doc = await (await c.get("/api/status")).json()
    finally:
        await c.close()
    assert doc["reachable"] is False
    assert "no status socket at" in doc["reason"]


async def test_surveys_casts_profile_and_events_come_from_the_journal(
    client: TestClient[Any, Any], journal: Path
) -> None:
    with JournalReader(journal) as reader:
        surveys = reader.surveys()
        reader.select_survey(surveys[-1].id)
        casts = reader.casts()
        events = reader.events()
    listed = (await (await client.get("/api/surveys")).json())["surveys"]
    assert [s["id"] for s in listed] == [s.id for s in surveys] and len(listed) == 2
    assert listed[-1]["stations"] == len(casts)
    body = await (await client.get(f"/api/surveys/{surveys[-1].id}/casts")).json()
    assert [c["id"] for c in body["casts"]] == [c.id for c in casts]
    # The map's frame: metres from the survey's south-west corner, all positive.
    assert min(c["east_m"] for c in body["casts"]) == 0.0
    assert min(c["north_m"] for c in body["casts"]) == 0.0
    assert max(c["east_m"] for c in body["casts"]) > 100
    measured = [c for c in casts if c.outcome == "completed"][-1]
    profile = await (await client.get(f"/api/casts/{measured.id}/profile")).json()
    assert len(profile["samples"]) == measured.samples
    assert max(s["depth_m"] for s in profile["samples"]) == pytest.approx(measured.reached_depth_m)
    assert [s["values"]["temperature"] for s in profile["sonde"]] == [
        24.0 - i * 0.5 for i in range(8)
    ]
    got = await (await client.get(f"/api/events?survey={surveys[-1].id}")).json()
    assert [e["kind"] for e in got["events"]] == [e.kind for e in events]
    latest = await (await client.get("/api/events")).json()
    assert latest == got


@pytest.mark.parametrize(
    ("path", "status"),
    [
        ("/api/surveys/99/casts", 404),
        ("/api/casts/9999/profile", 404),
        ("/api/events?survey=x", 400),
        ("/download/survey/99.csv", 404),
        ("/download/survey/1.exe", 404),
    ],
)
async def test_what_is_not_there_says_so_in_one_line(
    client: TestClient[Any, Any], path: str, status: int
) -> None:
    r = await client.get(path)
    assert r.status == status
    if r.content_type == "application/json":
        assert "\n" not in (await r.json())["error"]


async def test_only_get_is_answered(client: TestClient[Any, Any]) -> None:
    for method in ("POST", "PUT", "DELETE"):
        assert (await client.request(method, "/api/status")).status == 405


async def test_a_missing_journal_is_a_503_not_a_crash(
    socket: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    c = await client_for(Sources(socket=socket[0], journal=tmp_path / "none.db"))
    try:
        r = await c.get("/api/surveys")
        assert r.status == 503
        assert (await r.json())["error"].startswith("no journal yet")  # and not where
        assert not (tmp_path / "none.db").exists()  # read-only: nothing created
        assert (await c.get("/api/status")).status == 200
    finally:
        await c.close()


async def test_downloads_are_the_export_commands_files(
    client: TestClient[Any, Any], journal: Path, tmp_path: Path
) -> None:
    with JournalReader(journal) as reader:
        survey = reader.select_survey("latest")
        assert survey is not None
        samples, casts = reader.samples(), reader.casts()
    r = await client.get(f"/download/survey/{survey.id}.csv")
    assert r.status == 200 and r.content_type == "text/csv"
    assert f'filename="survey-{survey.id}.csv"' in r.headers["Content-Disposition"]
    text = await r.text()
    rows = list(csv.DictReader(line for line in io.StringIO(text) if not line.startswith("#")))
    assert len(rows) == len(samples)
    geo = json.loads(await (await client.get(f"/download/survey/{survey.id}.geojson")).read())
    assert geo["type"] == "FeatureCollection"
    stations = [f for f in geo["features"] if f["properties"].get("cast_id") is not None]
    assert len(stations) == len(casts)
    netCDF4 = pytest.importorskip("netCDF4")
    r = await client.get(f"/download/survey/{survey.id}.nc")
    assert r.status == 200
    path = tmp_path / "survey.nc"
    path.write_bytes(await r.read())
    with netCDF4.Dataset(path) as nc:
        assert nc.featureType == "profile"
    from tests.test_export import _cf_problems

    assert _cf_problems(path, tmp_path) == []


async def test_netcdf_without_netcdf4_is_a_clear_503(
    client: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "netCDF4", None)  # import netCDF4 now fails
    r = await client.get("/download/survey/2.nc")
    assert r.status == 503
    assert "netCDF4" in (await r.json())["error"]


async def test_the_page_and_its_assets_are_served_from_the_package(
    client: TestClient[Any, Any],
) -> None:
    total = 0
    r = await client.get("/")
    html = await r.text()
    total += len(html.encode())
    assert r.headers["Content-Security-Policy"].startswith("default-src 'self'")
    for asset in ("/static/page.css", "/static/page.js"):
        assert asset in html
        r = await client.get(asset)
        assert r.status == 200
        total += len(await r.read())
    assert "http://" not in html and "https://" not in html  # no CDN
    assert total < 200_000


def _basic(user: str, password: str) -> dict[str, str]:
    token = base64.b64encode(f"{user}:{password}".encode()).decode()
    return {"Authorization": f"Basic {token}"}


async def test_basic_auth_guards_every_path_when_a_password_is_set(
    journal: Path, socket: tuple[Path, dict[str, Any]]
) -> None:
    setting = auth.hash_password("sea-spray 7")
    c = await client_for(Sources(socket=socket[0], journal=journal, password_hash=setting))
    try:
        for path in ("/", "/api/status", "/api/surveys", "/download/survey/2.csv"):
            r = await c.get(path)
            assert r.status == 401 and r.headers["WWW-Authenticate"].startswith("Basic")
            assert (await c.get(path, headers=_basic("crew", "wrong"))).status == 401
            assert (await c.get(path, headers=_basic("crew", "sea-spray 7"))).status == 200
        assert (await c.get("/", headers={"Authorization": "Basic !!!"})).status == 401
    finally:
        await c.close()


def test_password_hashes_are_salted_and_checked() -> None:
    one, two = auth.hash_password("x"), auth.hash_password("x")
    assert one != two and one.startswith("scrypt$16384$8$1$")
    assert auth.verify_password("x", one) and auth.verify_password("x", two)
    assert not auth.verify_password("y", one)
    assert not auth.verify_password("x", "scrypt$1$2$3$bad$bad")
    from cc_daemon.config import Settings

    assert Settings.model_validate({"web": {"password_hash": one}}).web.password_hash == one
    with pytest.raises(ValueError, match="hash-password"):
        Settings.model_validate({"web": {"password_hash": "hunter2"}})
    with pytest.raises(ValueError, match="host:port"):
        Settings.model_validate({"web": {"listen": "0.0.0.0"}})


def test_hash_password_reads_stdin_and_prints_the_setting() -> None:
    env = {"PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-m", "cc_daemon", "web", "--hash-password"],
        input="sea-spray 7\n", capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    key, _, value = done.stdout.strip().partition(" = ")
    assert key == "password_hash"
    assert auth.verify_password("sea-spray 7", json.loads(value))
    empty = subprocess.run(
        [sys.executable, "-m", "cc_daemon", "web", "--hash-password"],
        input="\n", capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    assert empty.returncode == 2 and "empty password" in empty.stderr


def test_the_wheel_ships_the_page(tmp_path: Path) -> None:
    builder = pytest.importorskip("hatchling.builders.wheel")
    (wheel,) = builder.WheelBuilder(str(REPO)).build(directory=str(tmp_path), versions=["standard"])
    names = zipfile.ZipFile(wheel).namelist()
    for asset in ("index.html", "page.css", "page.js"):
        assert f"cc_daemon/cli/web/static/{asset}" in names


def test_a_bad_setting_exits_2_naming_the_key_and_a_busy_port_exits_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import socket as sockets

    from cc_daemon.cli.app import main

    config = tmp_path / "cc-daemon.toml"
    config.write_text('[web]\nlisten = "8080"\n')
    assert main(["web", "--config", str(config)]) == 2
    assert "web.listen" in capsys.readouterr().err
    with sockets.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        config.write_text(f'[web]\nlisten = "127.0.0.1:{port}"\n')
        code = main(["web", "--config", str(config), "--db", str(tmp_path / "x.db")])
    assert code == 1
    assert f"web.listen = 127.0.0.1:{port}:" in capsys.readouterr().err.splitlines()[-1]


async def test_journal_work_waits_its_turn_and_never_delays_the_status(
    client: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    import asyncio
    import threading

    from cc_daemon.cli.web import journaldata, server
    from tests.waitkit import DEADLINE_S, until

    running, most = 0, 0
    lock = threading.Lock()
    card = threading.Event()  # a stuck SD card, until the test frees it

    def slow_events(path: Path, survey: int | None) -> dict[str, Any]:
        nonlocal running, most
        with lock:
            running += 1
            most = max(most, running)
        card.wait(DEADLINE_S)
        with lock:
            running -= 1
        return {"events": []}

    monkeypatch.setattr(journaldata, "events", slow_events)
    readers = [asyncio.ensure_future(client.get("/api/events")) for _ in range(8)]
    try:
        await until(lambda: running == server.JOURNAL_AT_ONCE, "the journal's turns all taken")
        # Answered while every journal read is stuck: the status never waits behind them
        # (its time beside journal downloads: benchmarks/web.py).
        answer = await asyncio.wait_for(client.get("/api/status"), DEADLINE_S)
        doc = await answer.json()
        assert doc["reachable"] and running == server.JOURNAL_AT_ONCE
    finally:
        card.set()
    answers = await asyncio.gather(*readers)
    assert [r.status for r in answers] == [200] * 8
    assert most == server.JOURNAL_AT_ONCE


async def test_latest_is_the_sondes_last_reading_with_its_age(
    client: TestClient[Any, Any], journal: Path, tmp_path: Path
) -> None:
    with JournalReader(journal) as reader:
        last = reader.sonde_samples()[-1]
    body = await (await client.get("/api/latest")).json()
    assert body["survey"] == 2
    sonde = body["sonde"]
    assert sonde["values"]["temperature"] == last.values["temperature"] == 24.0 - 3.5
    assert sonde["depth_m"] == last.sonde_depth_m and sonde["status"] == "ok"
    assert sonde["age_s"] > 0  # the synthetic survey is years old: said, not hidden
    # A journal with no sonde: null, not an error.
    from cc_daemon.store import Journal
    from cc_daemon.store.synthetic import FakeClock, write_survey

    bare = tmp_path / "bare.db"
    clock = FakeClock()
    plain = Journal(bare, monotonic=clock.monotonic, wall=clock.wall)
    plain.open()
    write_survey(plain, clock, duration_s=60)
    plain.close()
    from cc_daemon.cli.web import journaldata

    assert journaldata.latest(bare, clock.wall())["sonde"] is None
    assert journaldata.latest(bare, clock.wall())["sonar"] is None
    # The daemon's own sonar: its last reading, an impossible one flagged, not hidden.
    plain = Journal(bare, monotonic=clock.monotonic, wall=clock.wall)
    plain.open()
    plain.record_sonar("/dev/ttyPING", 4200, 96)
    clock.advance(0.25)
    plain.record_sonar("/dev/ttyPING", 4294967295, 100)
    plain.close()
    sonar = journaldata.latest(bare, clock.wall())["sonar"]
    assert sonar["distance_m"] == 4294967.295 and sonar["valid"] is False
    assert sonar["confidence_pct"] == 100 and sonar["port"] == "/dev/ttyPING"


async def test_what_pages_ask_on_a_timer_is_read_once_for_all_of_them(
    client: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    import asyncio
    import time
    import types

    from cc_daemon.cli.web import journaldata, server
    from cc_daemon.store.synthetic import FakeClock

    # The page's server on a clock that moves only when told to: "a moment later" is
    # within the sharing time however long the machine takes to answer.
    clock = FakeClock()
    monkeypatch.setattr(
        server, "time", types.SimpleNamespace(monotonic=clock.monotonic, time=time.time)
    )
    calls: list[str] = []
    real_latest, real_surveys = journaldata.latest, journaldata.surveys

    def latest(path: Path, now: float) -> dict[str, Any]:
        calls.append("latest")
        return real_latest(path, now)

    def surveys(path: Path) -> dict[str, Any]:
        calls.append("surveys")
        return real_surveys(path)

    monkeypatch.setattr(journaldata, "latest", latest)
    monkeypatch.setattr(journaldata, "surveys", surveys)
    for _ in range(2):  # ten pages at once, then again a moment later
        answers = await asyncio.gather(
            *(client.get(path) for path in ["/api/latest", "/api/surveys"] * 5)
        )
        assert [r.status for r in answers] == [200] * 10
    assert sorted(calls) == ["latest", "surveys"]
    clock.advance(max(server.JOURNAL_SHARED_S.values()))  # both shared answers now stale
    again = [await client.get(path) for path in ("/api/latest", "/api/surveys")]
    assert [r.status for r in again] == [200, 200]
    assert sorted(calls) == ["latest", "latest", "surveys", "surveys"]


async def test_a_shared_latest_answer_gives_each_readings_age_as_of_its_own_answer(
    client: TestClient[Any, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The newcomer saw `taken 8.7 s ago` for 4.5 s on end: the age was the shared
    answer's, made once for every page."""
    import time
    import types

    from cc_daemon.cli.web import server

    now, later = time.time(), [0.0]  # monotonic still: the answer stays shared
    monkeypatch.setattr(
        server,
        "time",
        types.SimpleNamespace(monotonic=lambda: 1000.0, time=lambda: now + later[0]),
    )
    first = (await (await client.get("/api/latest")).json())["sonde"]
    later[0] = 3.0
    again = (await (await client.get("/api/latest")).json())["sonde"]
    assert again["wall_s"] == first["wall_s"]  # the same reading, the same shared answer
    assert again["age_s"] == pytest.approx(first["age_s"] + 3.0, abs=0.01)
