"""The field page in a real browser (Debian's headless Chromium), at a phone's width
(390 px) and a laptop's (1,280 px), against `cc-daemon --simulate` and `cc-daemon web`
as subprocesses (`tests.fieldpage`): each part renders in plain words with units; a
stranded probe's sentence appears and stays when the daemon stops; nothing is wider
than the screen, no text covers other text, no word breaks across two lines; every
download is a file its reader opens."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest

from tests import browserkit, webkit
from tests.fieldpage import (
    SPILLS_JS,
    TEXT_JS,
    WIDTHS,
    Day,
    at_width,
    fetch,
    look,
    ready,
    run_the_day,
    settle,
    web,
)

# Two simulated surveys and a browser: minutes under a loaded full suite.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

UNITS = {
    "#summary": [" m", "bit/s", " %", " GB", "° N", "° W", " s ago"],
    "#casts": [" m", "water ", " UTC"],
}


def _checks(browser: Any, state: str) -> None:
    """At each width: the page as a person sees it, and the words and units of `state`."""
    js = browser.execute_script
    for width in WIDTHS:
        at_width(browser, width)
        ready(browser, state)
        seen = look(browser)
        page, zoom = seen["wide"]
        assert page <= width and zoom == 1, (state, width, seen["wide"])  # no sideways scroll
        assert seen["overlaps"] == [], (state, width)
        assert seen["broken"] == [], (state, width)
        assert seen["spills"] == [], (state, width)
    text = {where: js(TEXT_JS, where) for where in ("#state", "#summary", "#casts", "#banner")}
    mode = js(TEXT_JS, "#mode")
    assert mode == ("DAEMON NOT ANSWERING" if state == "gone" else "SIMULATED: no probe moves")
    if state != "gone":
        for where, units in UNITS.items():
            for unit in units:
                assert unit in text[where], (state, where, unit, text[where])
        if "status\nok" in text["#summary"]:  # the sonde's last reading, every value's unit
            for unit in ("°C", "mg/L", "RFU", " %"):
                assert unit in text["#summary"].split("Sonde (last reading)")[1], unit
    # One count: the chosen survey's measured stations are its casts measured.
    counted = js("return document.querySelector('#surveys button.chosen .measured').textContent")
    measured = js(
        "return [...document.querySelectorAll('#casts button')]"
        ".filter((b) => b.children[2].textContent === 'measured')"
        ".map((b) => b.children[0].textContent.split(' ')[0])"
    )
    assert counted == f"{len(set(measured))} measured", (counted, measured)
    # The map names the stations as the simulator does; profiles have axes with units.
    labels = js(
        "return [...document.querySelectorAll('#map .station-label')].map(t => t.textContent)"
    )
    assert any(label.startswith("S1 ") for label in labels), labels
    titles = js(
        "return [...document.querySelectorAll('#profiles .axis-title')].map(t => t.textContent)"
    )
    assert "depth (m)" in titles and "time (s)" in titles and "temperature (°C)" in titles, titles
    # The way down and the way up are drawn apart; a stranded probe's readings are held.
    series = "return document.querySelectorAll('#profiles .series.' + arguments[0]).length"
    for way in ("held",) if state in ("stranded", "gone") else ("down", "up"):
        assert js(series, way) >= 1, (state, way)
    # The day's science: the lake floor under the map, each station's numbers, the
    # binned profile over the readings, the thermocline marked where there is one.
    if state in ("idle", "casting"):  # the first survey's: three stations measured
        # Made again when the journal has grown and the making is due (science.py).
        settle(browser, "the lake floor on the map", lambda: "Lake floor from " in js(
            TEXT_JS, "#bed-legend"))  # fmt: skip
        assert js("return document.querySelectorAll('#map .bed-cell').length") >= 1
        numbers = js(TEXT_JS, "#numbers")
        assert "Thermocline (m)" in numbers and "S1 · cast" in numbers, numbers
        # Bins made from every reading of the cast (the page asks again when they are due).
        settle(browser, "the binned profile", lambda: js(series, "binned") >= 1)
        assert js(series, "raw") == 0  # under the bins, the readings are points only
    # Events are sentences, their details folded away.
    events = js("return [...document.querySelectorAll('#events > li')].map(li => li.innerText)")
    assert any(" at S1 started: " in e for e in events), events[:5]
    assert js("return document.querySelectorAll('#events details:not([open])').length") >= 1
    if state == "idle":
        assert "No cast running" in text["#state"] and "The probe is home" in text["#state"]
    if state == "casting":
        assert "going down" in text["#state"] and " m planned" in text["#state"]
        assert js("return document.querySelectorAll('#live-chart .measured-line').length") == 1
    if state == "stranded":
        _stranded_said(text["#banner"])
    if state == "gone":
        assert "The daemon does not answer" in text["#banner"], text["#banner"]
        assert "Last known" in text["#banner"], text["#banner"]
        _stranded_said(text["#banner"])  # the last known state stays on the page
        assert "as of" in text["#state"] and "stranded" in text["#state"]


def _stranded_said(banner: str) -> None:
    assert "The probe is stranded" in banner, banner
    assert "What happened: home not reached: line jammed at 0.50 m" in banner, banner
    assert "Where the probe is: at 0.50 m" in banner, banner
    assert "What the autopilot is told: R-L" in banner and "instead of R-F" in banner, banner
    assert "To release:" in banner and "cc-daemon winch home" in banner, banner


def _science_files(browser: Any) -> None:
    """The science's downloads: each a file its reader opens."""
    netcdf4 = pytest.importorskip("netCDF4")
    links = browser.execute_script(
        "return [...document.querySelectorAll('#science-files a')]"
        ".map(a => [a.dataset.format, a.href])"
    )
    names = [name for name, _ in links]
    for name in ("bathymetry.nc", "contours.geojson", "profiles.nc", "profiles.csv",
                 "stations.csv", "stations.geojson"):  # fmt: skip
        assert name in names, (name, names)
    for name, link in links:
        body = fetch(link)
        if name.endswith(".csv"):
            lines = [line for line in body.decode().splitlines() if not line.startswith("#")]
            assert list(csv.DictReader(lines)), name
        elif name.endswith(".geojson"):
            assert json.loads(body)["type"] == "FeatureCollection", name
        elif name.endswith(".nc"):
            with netcdf4.Dataset("in-memory.nc", memory=body) as nc:
                assert nc.dimensions, name
        else:
            assert body[:4] in (b"II*\x00", b"MM\x00*"), name  # a TIFF


def _downloads(browser: Any) -> None:
    """Every download of the chosen survey: a file its reader opens, with data in it."""
    netcdf4 = pytest.importorskip("netCDF4")
    links = browser.execute_script(
        "return [...document.querySelectorAll('#downloads a')].map(a => [a.dataset.format, a.href])"
    )
    assert [fmt for fmt, _ in links] == ["csv", "sonde.csv", "sonde.nc", "geojson", "nc"]
    for fmt, link in links:
        body = fetch(link)
        if fmt.endswith("csv"):
            text = body.decode()
            lines = [line for line in text.splitlines() if not line.startswith("#")]
            rows = list(csv.DictReader(lines))
            assert rows, fmt
            key = "depth_low_m" if fmt == "csv" else "temperature [degC]"
            assert key in rows[0], (fmt, rows[0].keys())
        elif fmt == "geojson":
            doc = json.loads(body)
            assert doc["type"] == "FeatureCollection" and doc["features"]
        else:
            with netcdf4.Dataset("in-memory.nc", memory=body) as nc:
                assert nc.featureType == "profile" and nc.dimensions


def test_the_field_page_through_a_day_at_a_phones_and_a_laptops_width(tmp_path: Path) -> None:
    def visit(day: Day, state: str, browser: Any) -> None:
        js = browser.execute_script
        if state == "casting-live":
            # The live chart grows while the cast runs, without a reload.
            def drawn() -> tuple[Any, int]:
                count = js("const l = document.querySelector('#live-chart-line');"
                           " return l ? l.points.length : 0")  # fmt: skip
                return js("return document.querySelector('#live-caption').textContent"), count

            first = settle(browser, "a cast on the live chart", lambda: drawn()[1] and drawn())
            settle(browser, "the chart advancing", lambda: drawn() != first)
            return
        if state == "stranded-live":
            settle(browser, "the stranded sentence", lambda: "The probe is stranded" in js(
                TEXT_JS, "#banner"))  # fmt: skip
            _stranded_said(js(TEXT_JS, "#banner"))
            # Opened on the first survey, the page followed the second and its station.
            settle(browser, "the new survey's map", lambda: "survey 2" in js(TEXT_JS, "#map-title"))
            settle(browser, "the station named", lambda: " at S1: " in js(TEXT_JS, "#state"))
            return
        if state == "gone-live":  # the real daemon stopped with the probe down
            settle(browser, "the daemon gone", lambda: "does not answer" in js(TEXT_JS, "#banner"))
            _stranded_said(js(TEXT_JS, "#banner"))
            return
        _checks(browser, state)
        if state == "idle":
            _downloads(browser)
            _science_files(browser)

    run_the_day(tmp_path, visit)


def test_any_fault_key_raises_the_banner_and_unknown_sections_are_shown(tmp_path: Path) -> None:
    webkit.make_journal(tmp_path / "sim.db")
    with web(tmp_path) as (url, sock, _):
        doc = webkit.status(
            winch={"fault": "stalled at 2.5 m: probe stranded"},
            counters={"faults_total": 3},  # a count of faults past: no banner
        )
        with browserkit.chromium() as browser, browserkit.status_socket(sock, doc):
            browser.get(url)
            js = browser.execute_script
            settle(
                browser, "the fault banner", lambda: "stalled at 2.5 m" in js(TEXT_JS, "#banner")
            )
            banner = js(TEXT_JS, "#banner")
            assert "The winch reports a fault" in banner and "faults total" not in banner
            assert "tide_gauge" in js("return document.querySelector('#sections').textContent")
            # A key no version of the page knows, naming a fault, raises it too.
            doc["tide_gauge"] = {"fault": "float stuck"}
            settle(browser, "the new key", lambda: "float stuck" in js(TEXT_JS, "#banner"))
            # ...and the check sees text laid over text when there is some.
            js(
                "const s = document.createElement('span'); s.textContent = 'OVER';"
                "s.style = 'position:absolute;top:8px;left:14px'; document.body.append(s)"
            )
            assert js(browserkit.OVERLAPS_JS)
            # ...and a word broken across two lines.
            js(
                "const p = document.createElement('p'); p.textContent = 'unbreakable'.repeat(9);"
                "p.style = 'width:5em;overflow-wrap:anywhere'; document.body.append(p)"
            )
            assert look(browser)["broken"]
            # ...and text running out of its card: added and looked for in one script, as the
            # page redraws its cards at each status it reads.
            spilt = js(
                "const s = document.createElement('span'); s.className = 'chunk';"
                "s.textContent = 'spilt '.repeat(60); document.querySelector('.card dd').append(s);"
                + SPILLS_JS
            )
            assert spilt
