"""The field page's day, for its browser test and its screenshots: `cc-daemon web` and
two simulated surveys as subprocesses, the status documents the real daemon served
at each state (idle, casting, stranded) kept and served again for as long as the
checks take, and the checks a person's eyes would make, in JavaScript.

`python -m tests.fieldpage` runs the day and writes the screenshots that
docs/web.md shows into docs/img/ (each state at 390 and 1,280 px).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from tests import browserkit
from tests.daemonkit import REPO
from tests.waitkit import DEADLINE_S, until_sync

WIDTHS = (390, 1280)
HEIGHTS = {390: 844, 1280: 900}
SIMULATE = [sys.executable, "-m", "cc_daemon", "--simulate", "--plain"]

# Every element whose text shows, its words: a word (letters and digits) broken across
# two lines has two boxes on two lines. Text in closed <details> and in SVG is left out.
WORD_BREAKS_JS = r"""
const found = [];
const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
const range = document.createRange();
for (let node = walker.nextNode(); node; node = walker.nextNode()) {
  const parent = node.parentElement;
  if (!parent || parent.closest("svg") || parent.closest("details:not([open]) > :not(summary)")
      || parent.closest("[hidden]") || !parent.getClientRects().length) continue;
  for (const m of node.textContent.matchAll(/[\p{L}\p{N}]+/gu)) {
    range.setStart(node, m.index);
    range.setEnd(node, m.index + m[0].length);
    const tops = new Set([...range.getClientRects()].filter((r) => r.width > 0)
      .map((r) => Math.round(r.top)));
    if (tops.size > 1) found.push(m[0] + " in: " + node.textContent.slice(0, 60));
  }
}
return found;
"""
# Two labels of one drawing over each other (the HTML's text is OVERLAPS_JS's).
SVG_OVERLAPS_JS = """
const found = [];
for (const svg of document.querySelectorAll("svg")) {
  const boxes = [...svg.querySelectorAll("text")].map((t) => [t, t.getBoundingClientRect()])
    .filter(([, r]) => r.width > 0 && r.height > 0);
  for (let i = 0; i < boxes.length; i++) {
    for (let j = i + 1; j < boxes.length; j++) {
      const [a, ra] = boxes[i], [b, rb] = boxes[j];
      const w = Math.min(ra.right, rb.right) - Math.max(ra.left, rb.left);
      const h = Math.min(ra.bottom, rb.bottom) - Math.max(ra.top, rb.top);
      if (w > 1 && h > 1) found.push(svg.id + ": " + a.textContent + " / " + b.textContent);
    }
  }
}
return found;
"""
# The page's width and the zoom: a phone's browser zooms out (scale < 1) to show a page
# wider than its screen, and its layout viewport (innerWidth) grows with it.
WIDE_JS = "return [document.documentElement.scrollWidth, window.visualViewport.scale]"
# Text that runs out of the box it is in (a card, a row, a figure): visible over its border.
SPILLS_JS = """
const found = [];
const range = document.createRange();
for (const node of document.body.querySelectorAll("*")) {
  if (node.closest("svg") || node.closest("details:not([open]) > :not(summary)")) continue;
  const box = node.closest(".card, figure, .rows button, .files li, .banner, .state, header, nav");
  if (!box) continue;
  const edge = box.getBoundingClientRect();
  for (const c of node.childNodes) {
    if (c.nodeType !== 3 || !c.textContent.trim()) continue;
    range.selectNodeContents(c);
    for (const r of range.getClientRects()) {
      if (r.width > 0 && (r.right > edge.right + 1 || r.left < edge.left - 1)) {
        found.push(c.textContent.slice(0, 40));
      }
    }
  }
}
return found;
"""
# Every drawing made at the width it is shown (one SVG unit a CSS pixel).
DRAWN_JS = """
return [...document.querySelectorAll("svg[viewBox]")].every((svg) =>
  Math.abs(svg.viewBox.baseVal.width - svg.getBoundingClientRect().width) < 2);
"""
TEXT_JS = "return document.querySelector(arguments[0]).innerText"


def env(**extra: str) -> dict[str, str]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
    return {**clean, "PYTHONPATH": str(REPO), **extra}


def get_json(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url, timeout=DEADLINE_S) as answer:
        doc: dict[str, Any] = json.load(answer)
    return doc


def fetch(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=DEADLINE_S) as answer:
        assert answer.status == 200, url
        body: bytes = answer.read()
    return body


@contextlib.contextmanager
def web(workdir: Path) -> Iterator[tuple[str, Path, Path]]:
    """`cc-daemon web` on a free port: (its URL, the socket it asks, the journal)."""
    sock, db = workdir / "status.sock", workdir / "sim.db"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cc_daemon", "web", "--listen", "127.0.0.1:0",
         "--socket", str(sock), "--db", str(db)],
        stdin=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env(), cwd=workdir,
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


class Day:
    """The simulated surveys the page follows, and the status documents kept from them."""

    def __init__(self, url: str, sock: Path, db: Path, workdir: Path) -> None:
        self.url, self.sock, self.db, self.workdir = url, sock, db, workdir
        self.kept: dict[str, dict[str, Any]] = {}
        self._running: list[subprocess.Popen[bytes]] = []
        self._logs: dict[int, Path] = {}

    def simulate(self, *extra: str) -> subprocess.Popen[bytes]:
        """A simulated survey; what it says goes to a log beside the journal."""
        log = self.workdir / f"simulate-{len(self._running) + 1}.log"
        with log.open("wb") as out:
            sim = subprocess.Popen(
                [*SIMULATE, "--db", str(self.db), *extra],
                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                env=env(CC_DAEMON_STATUS__PATH=str(self.sock), PYTHONFAULTHANDLER="1",
                        PYTHONUNBUFFERED="1"),
                cwd=self.workdir,
            )  # fmt: skip
        self._running.append(sim)
        self._logs[sim.pid] = log
        return sim

    def ends(self, sim: subprocess.Popen[bytes], within_s: float) -> None:
        """Wait for a survey to end. One that does not is made to dump its threads' stacks
        (faulthandler, on SIGABRT), and the test fails with the end of what it said."""
        try:
            sim.wait(within_s)
        except subprocess.TimeoutExpired:
            sim.send_signal(signal.SIGABRT)
            sim.wait(10)
            said = self._logs[sim.pid].read_text(errors="replace")
            raise AssertionError(
                f"the simulated survey had not ended after {within_s:.0f} s; it said:\n"
                + said[-20000:]
            ) from None

    def status(self) -> dict[str, Any]:
        return get_json(self.url + "api/status")

    def keep(self, name: str, test: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
        """Wait for a status document of the running daemon that passes `test`; keep it."""

        def seen() -> dict[str, Any] | None:
            doc = self.status()
            return doc if doc.get("reachable") and test(doc) else None

        doc = until_sync(seen, f"the daemon {name}", DEADLINE_S * 2, every=0.2)
        self.kept[name] = {k: v for k, v in doc.items() if k not in ("reachable", "read_at")}
        return doc

    @contextlib.contextmanager
    def replay(self, name: str) -> Iterator[None]:
        """Serve the kept document `name` on the daemon's socket, as the daemon did."""
        with browserkit.status_socket(self.sock, self.kept[name]):
            until_sync(lambda: self.status().get("reachable"), "the replayed status", DEADLINE_S)
            yield

    def stop_all(self) -> None:
        for sim in self._running:
            if sim.poll() is None:
                sim.kill()
                sim.wait(10)


def casting(doc: dict[str, Any]) -> bool:
    return doc["cast"]["phase"] in ("descending", "dwelling") and doc["cast"]["depth_m"] > 1.0


def idle_after_a_cast(doc: dict[str, Any]) -> bool:
    return doc["cast"]["phase"] == "idle" and doc["counters"]["casts_completed"] >= 1


def stranded(doc: dict[str, Any]) -> bool:
    return bool(doc["cast"].get("fault_reported"))


def at_width(browser: Any, width: int, height: int | None = None) -> None:
    browser.execute_cdp_cmd(
        "Emulation.setDeviceMetricsOverride",
        {"width": width, "height": height or HEIGHTS[width], "deviceScaleFactor": 1,
         "mobile": width < 600},
    )  # fmt: skip


def settle(browser: Any, what: str, check: Callable[[], Any]) -> Any:
    return until_sync(check, what, DEADLINE_S, every=0.1)


def look(browser: Any) -> dict[str, Any]:
    """What a person's eyes check: nothing wider than the screen, no text over text, no
    word broken across two lines."""
    js = browser.execute_script
    return {
        "wide": js(WIDE_JS),
        "overlaps": js(browserkit.OVERLAPS_JS) + js(SVG_OVERLAPS_JS),
        "broken": js(WORD_BREAKS_JS),
        "spills": js(SPILLS_JS),
    }


def shot(browser: Any, path: Path, *, whole: bool = False) -> None:
    """A screenshot of the screen (or of the whole page), at the width set."""
    width = browser.execute_script("return window.innerWidth")
    if whole:
        at_width(browser, width, browser.execute_script("return document.body.scrollHeight"))
        settle(browser, "the drawings redrawn", lambda: browser.execute_script(DRAWN_JS))
    browser.execute_script("window.scrollTo(0, 0)")
    browser.save_screenshot(str(path))
    if whole:
        at_width(browser, width)


def run_the_day(workdir: Path, visit: Callable[[Day, str, Any], None]) -> None:
    """The day: a survey (idle and casting kept), a stranded one (kept), then the daemon
    gone. `visit(day, state, browser)` is called at each state with the page loaded."""
    with web(workdir) as (url, sock, db), browserkit.chromium() as browser:
        day = Day(url, sock, db, workdir)
        try:
            first = day.simulate("--stations", "3")
            day.keep("casting", casting)
            browser.get(url)
            visit(day, "casting-live", browser)
            day.keep("idle", idle_after_a_cast)
            day.ends(first, DEADLINE_S * 3)
            for state in ("idle", "casting"):
                with day.replay(state):
                    browser.get(url)
                    visit(day, state, browser)
            # The page stays open: it follows the new survey and its cast on its own.
            second = day.simulate("--winch-fail-home", "--stations", "2")
            day.keep("stranded", stranded)
            visit(day, "stranded-live", browser)
            day.ends(second, DEADLINE_S * 3)
            visit(day, "gone-live", browser)  # the real daemon stopped: exit 130
            with day.replay("stranded"):
                browser.get(url)
                visit(day, "stranded", browser)
            visit(day, "gone", browser)
        finally:
            day.stop_all()


def screenshots(target: Path) -> None:
    """Each state at each width, as docs/web.md shows them."""

    def visit(day: Day, state: str, browser: Any) -> None:
        if state.endswith("-live"):
            return
        for width in WIDTHS:
            at_width(browser, width)
            ready(browser, state)
            shot(browser, target / f"field-page-{state}-{width}.png")
            if state == "idle":
                shot(browser, target / f"field-page-today-{width}.png", whole=True)

    with tempfile.TemporaryDirectory(prefix="cc-daemon-shots-") as tmp:
        run_the_day(Path(tmp), visit)


def ready(browser: Any, state: str) -> None:
    """Wait until the page shows `state` and has drawn the day's map and profiles."""
    js = browser.execute_script
    settle(
        browser, "the map", lambda: js("return document.querySelectorAll('#map .station').length")
    )
    axes = "return document.querySelectorAll('#profiles svg .axes').length"
    settle(browser, "the profiles", lambda: js(axes) >= 3)
    settle(browser, "the sonde's card", lambda: "Sonde (last reading)" in js(TEXT_JS, "#summary"))
    settle(
        browser,
        "the day's science",
        lambda: (
            js(TEXT_JS, "#numbers")
            and "Working out" not in js(TEXT_JS, "#numbers") + js(TEXT_JS, "#science-files")
        ),
    )
    if not state.endswith("-live"):  # the journal no longer grows: the science catches up
        science = "return document.querySelector('#today').innerText"
        # Made again when due: 20 times the last making's time, longer on a loaded machine.
        until_sync(lambda: "has grown since" not in js(science), "the day's science made again",
                   DEADLINE_S * 3, every=0.5)  # fmt: skip
    settle(browser, "the drawings at the width shown", lambda: js(DRAWN_JS))
    words = {"idle": "No cast running", "casting": "going down", "stranded": "stranded",
             "gone": "The daemon does not answer"}[state.removesuffix("-live")]  # fmt: skip
    where = "#banner" if state.startswith("gone") else "#state"
    settle(browser, f"the page {state}", lambda: words in js(TEXT_JS, where))
    js("return new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)))")


if __name__ == "__main__":
    out = REPO / "docs" / "img"
    out.mkdir(parents=True, exist_ok=True)
    screenshots(out)
    for png in sorted(out.glob("field-page-*.png")):
        print(png.relative_to(REPO), png.stat().st_size)
