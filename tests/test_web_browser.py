"""The field page in a real browser (Debian's headless Chromium) at a phone's width,
against `cc-daemon --simulate` and `cc-daemon web` as subprocesses.

One browser session and one simulated survey for every check: each costs seconds."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests import browserkit, webkit
from tests.daemonkit import REPO
from tests.waitkit import DEADLINE_S, until_sync

# A simulated survey, a stalled one and a browser: slow under a loaded full suite.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
    return {**env, "PYTHONPATH": str(REPO), **extra}


def _until(what: str, check: Callable[[], Any]) -> Any:
    """Poll `check` (a round trip to the browser) every 0.1 s until it is true-ish."""
    return until_sync(check, what, DEADLINE_S, every=0.1)


SIMULATE = [sys.executable, "-m", "cc_daemon", "--simulate", "--stations", "3", "--plain"]
SUMMARY = "return $('#summary').textContent"
BANNER = "return $('#banner').hidden ? '' : $('#banner').textContent"
LIVE_POINTS = "const l = $('#live-chart-line'); return l ? l.points.length : 0"
SURVEY_ROWS = "return document.querySelectorAll('#surveys tbody tr[data-survey]').length"
PROFILE_TITLE = "return $('#profile-title').textContent"
PROFILE_LINES = "return document.querySelectorAll('#profile polyline').length"


def _get_json(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url, timeout=DEADLINE_S) as answer:
        doc: dict[str, Any] = json.load(answer)
    return doc


def _status(url: str) -> dict[str, Any]:
    doc = _get_json(url + "api/status")
    return doc if doc["reachable"] else {"counters": {"casts_completed": 0}}


@pytest.fixture
def web(tmp_path: Path) -> Iterator[tuple[str, Path, Path]]:
    """`cc-daemon web` on a free port: (its URL, the socket it asks, the journal)."""
    sock, db = tmp_path / "status.sock", tmp_path / "sim.db"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cc_daemon", "web", "--listen", "127.0.0.1:0",
         "--socket", str(sock), "--db", str(db)],
        stdin=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=_env(), cwd=tmp_path,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        url = None
        for line in proc.stderr:
            found = re.search(r"(http://127\.0\.0\.1:\d+/)", line)
            if found:
                url = found.group(1)
                break
        assert url, f"cc-daemon web did not start (exit {proc.poll()})"
        yield url, sock, db
    finally:
        proc.terminate()
        proc.wait(DEADLINE_S)
        assert proc.stderr is not None
        proc.stderr.close()


def test_the_page_follows_a_simulated_survey_at_a_phones_width(
    web: tuple[str, Path, Path], tmp_path: Path
) -> None:
    url, sock, db = web
    sims: list[subprocess.Popen[bytes]] = []

    def simulate(*extra: str) -> subprocess.Popen[bytes]:
        sims.append(
            subprocess.Popen(
                [*SIMULATE, "--db", str(db), *extra],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                env=_env(CC_DAEMON_STATUS__PATH=str(sock)),
                cwd=tmp_path,
            )
        )
        return sims[-1]

    def stop(sim: subprocess.Popen[bytes]) -> None:
        sim.terminate()  # the daemon brings the probe home and exits
        sim.wait(DEADLINE_S)

    sim = simulate()
    try:
        with browserkit.chromium() as browser:
            browser.get(url)
            js = browser.execute_script
            # Against the running daemon: it says, in words, that no probe moves.
            _until("SIMULATED shown", lambda: "SIMULATED" in js("return $('#mode').textContent"))
            # The live chart grows while a cast runs, without a reload.
            first = _until("a cast on the live chart", lambda: js(LIVE_POINTS))
            _until("the chart advancing", lambda: js(LIVE_POINTS) >= first + 2)
            assert js("return $('#live-caption').textContent").startswith("Cast ")
            _until("a cast completed", lambda: _status(url)["counters"]["casts_completed"])
            # The sonde's last reading, from the journal (every 5 s).
            _until("the sonde's card", lambda: "Sonde (last reading)" in js(SUMMARY))
            stop(sim)
            # The daemon gone: said at the top, not hidden.
            _until("the unreachable banner", lambda: "does not answer" in js(BANNER))
            # A fault injected in the simulation (the winch stalls): the banner, while
            # it lasts (about 2 s per stalled cast), on a second survey in the journal.
            stall = simulate("--winch-stall")
            _until("the stall's banner", lambda: "winch.fault: stall at" in js(BANNER))
            stop(stall)
            # Any fault key in the status document, and sections no version of the
            # page knows, are shown too.
            doc = webkit.status(
                winch={"fault": "stalled at 2.5 m: probe stranded"},
                counters={"faults_total": 3},  # a count of faults past: no banner
            )
            with browserkit.status_socket(sock, doc):
                _until("the fault banner", lambda: "winch.fault: stalled at 2.5 m" in js(BANNER))
                assert "tide_gauge" in js("return $('#sections').textContent")
                assert "faults_total" not in js(BANNER)
                # Today: the first survey's last cast, its profile drawn from the journal.
                browser.get(url)
                _until("the surveys listed", lambda: js(SURVEY_ROWS) == 2)
                js("document.querySelector('#surveys tr[data-survey=\"1\"]').click()")
                casts = _get_json(url + "api/surveys/1/casts")["casts"]
                cast = [c["id"] for c in casts if c["outcome"] == "completed"][-1]
                _until(
                    "the profile drawn",
                    lambda: (
                        js(PROFILE_TITLE).startswith(f"Profile of cast {cast}:")
                        and js(PROFILE_LINES) >= 3
                    ),
                )
                assert js("return document.querySelectorAll('#map circle.station').length") >= 1
                # A phone's width: nothing wider than the screen, no text over text.
                assert js("return document.documentElement.scrollWidth") <= 390
                assert js(browserkit.OVERLAPS_JS) == []
                browser.save_screenshot(str(tmp_path / "phone.png"))
                # ...and the check sees text laid over text when there is some.
                js(
                    "const s = document.createElement('span'); s.textContent = 'OVER';"
                    "s.style = 'position:absolute;top:8px;left:14px'; document.body.append(s)"
                )
                assert js(browserkit.OVERLAPS_JS)
                links = js("return [...document.querySelectorAll('#downloads a')].map(a => a.href)")
        assert [link.rsplit(".", 1)[1] for link in links] == ["csv", "geojson", "nc"]
        for link in links[:2]:
            with urllib.request.urlopen(link, timeout=DEADLINE_S) as answer:
                assert answer.status == 200 and len(answer.read()) > 100
        assert (tmp_path / "phone.png").stat().st_size > 10_000
    finally:
        for sim in sims:
            if sim.poll() is None:
                sim.kill()
                sim.wait(10)
