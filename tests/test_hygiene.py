"""The suite's own leak check (tests/hygiene.py), run on a small suite of its own in a
subprocess: a leak fails the test that made it, and the next test is untouched."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from tests.daemonkit import REPO

CONFTEST = """
import pytest
from tests import hygiene

hygiene.THREAD_END_S = 1.0  # the leaky thread below never ends: no need to wait long

@pytest.fixture(autouse=True)
def _no_leaks():
    yield from hygiene.no_leaks()

@pytest.fixture(autouse=True)
def _terminal_signals():
    yield from hygiene.terminal_signals()
"""

LEAKY = """
import signal
import subprocess
import sys
import threading

class Cycle:
    def __init__(self, path):
        self.me = self
        self.file = open(path, "rb")  # never closed: found when the cycle is collected

def test_leaves_a_process_running():
    subprocess.Popen([sys.executable, "-c", "import time; time.sleep(300)"])

def test_after_the_process_is_clean():
    pass

def test_leaves_a_file_open_in_a_cycle(tmp_path):
    (tmp_path / "f").write_bytes(b"x")
    Cycle(tmp_path / "f")

def test_after_the_file_is_clean():
    pass

def test_leaves_a_thread_running():
    threading.Thread(target=threading.Event().wait, name="forever", daemon=True).start()

def test_after_the_thread_is_clean():
    pass

def test_sigint_is_a_keyboard_interrupt_as_at_a_terminal():
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
"""


def test_a_leak_fails_the_test_that_made_it_and_only_that_one(tmp_path: Path) -> None:
    (tmp_path / "conftest.py").write_text(CONFTEST)
    (tmp_path / "test_leaky.py").write_text(textwrap.dedent(LEAKY))
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-p",
            "no:cacheprovider",
            "-p",
            "no:asyncio",
            "-W",
            "error",
            "-rA",
            str(tmp_path / "test_leaky.py"),
        ],
        check=False,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        # As `make test &` from a script starts it: SIGINT ignored, inherited by exec.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    out = done.stdout
    assert done.returncode == 1, out
    assert "ERROR test_leaky.py::test_leaves_a_process_running" in out, out
    assert "left processes running (killed now)" in out
    assert "ERROR test_leaky.py::test_leaves_a_file_open_in_a_cycle" in out
    assert "ResourceWarning: unclosed file" in out
    assert "ERROR test_leaky.py::test_leaves_a_thread_running" in out
    assert "the test left threads running: ['forever']" in out
    for clean in (
        "test_after_the_process_is_clean",
        "test_after_the_file_is_clean",
        "test_after_the_thread_is_clean",
        "test_sigint_is_a_keyboard_interrupt_as_at_a_terminal",
    ):
        assert f"PASSED test_leaky.py::{clean}" in out, out
