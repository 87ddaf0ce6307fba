"""Debian's headless Chromium, driven by selenium through Debian's chromedriver (no
browser download), and a status socket served from a thread for a blocking test."""

from __future__ import annotations

import asyncio
import shutil
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.daemon.status_server import StatusServer
from tests.waitkit import DEADLINE_S

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
]
PHONE = {"width": 390, "height": 844, "deviceScaleFactor": 1, "mobile": True}

# Every element whose own text shows: two of them must never cover each other.
OVERLAPS_JS = """
const boxes = [];
for (const node of document.body.querySelectorAll("*")) {
  if (node.closest("svg") || node.closest("details:not([open]) > :not(summary)")) continue;
  const own = [...node.childNodes].some((c) => c.nodeType === 3 && c.textContent.trim());
  if (!own) continue;
  const range = document.createRange();
  for (const c of node.childNodes) {
    if (c.nodeType !== 3 || !c.textContent.trim()) continue;
    range.selectNodeContents(c);
    for (const r of range.getClientRects()) {
      if (r.width > 0 && r.height > 0) boxes.push([node, r]);
    }
  }
}
const found = [];
for (let i = 0; i < boxes.length; i++) {
  for (let j = i + 1; j < boxes.length; j++) {
    const [a, ra] = boxes[i], [b, rb] = boxes[j];
    const w = Math.min(ra.right, rb.right) - Math.max(ra.left, rb.left);
    const h = Math.min(ra.bottom, rb.bottom) - Math.max(ra.top, rb.top);
    if (w > 1 && h > 1) found.push(a.textContent.slice(0, 30) + " / " + b.textContent.slice(0, 30));
  }
}
return found;
"""


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless Chromium with a fresh profile, or skip saying what is missing."""
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    for path in (CHROMIUM, CHROMEDRIVER):
        if not path.exists():
            pytest.skip(f"{path} missing: `make test` installs Debian's chromium, chromium-driver")
    profile = tempfile.mkdtemp(prefix="cc-daemon-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in [*FLAGS, f"--user-data-dir={profile}"]:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
    try:
        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", PHONE)
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


@contextmanager
def status_socket(path: Path, document: dict[str, Any]) -> Iterator[StatusServer]:
    """A real StatusServer serving `document`, on its own event loop in a thread."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, name="status-socket", daemon=True)
    thread.start()
    server = StatusServer(path, lambda: document)
    try:
        asyncio.run_coroutine_threadsafe(server.start(), loop).result(DEADLINE_S)
        yield server
    finally:
        asyncio.run_coroutine_threadsafe(server.close(), loop).result(DEADLINE_S)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(DEADLINE_S)
        loop.close()
