"""Shared fixtures."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.ground.logsetup import reset_logging
from cc_daemon.store import spill
from tests import hygiene, schedule
from tests.daemonkit import DaemonProcess


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest tests first, so that the workers end together (tests/schedule.py)."""
    schedule.longest_first(items)


# First of the autouse fixtures, so set up before and torn down after every other one.
@pytest.fixture(autouse=True)
def _no_leaks() -> Iterator[None]:
    """A process left running, or an unclosed file, socket or subprocess, fails the
    test that left it (tests/hygiene.py)."""
    yield from hygiene.no_leaks()


@pytest.fixture(autouse=True)
def _terminal_signals() -> Iterator[None]:
    """Every test starts with a terminal's signal dispositions, however the suite was
    started (`make test &` from a script ignores SIGINT): tests/hygiene.py."""
    yield from hygiene.terminal_signals()


@pytest.fixture(autouse=True)
def _fresh_logging() -> Iterator[None]:
    """Commands run in-process configure structlog globally; undo it after each test."""
    yield
    reset_logging()


@pytest.fixture(autouse=True)
def _no_system_runtime_dir(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The journal's last spill directories (/run/cc-daemon, $XDG_RUNTIME_DIR) are
    not the test's: a test that wants one sets $RUNTIME_DIRECTORY."""
    monkeypatch.setattr(spill, "SYSTEM_RUNTIME_DIR", tmp_path_factory.mktemp("run") / "no" / "x")
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)


@pytest.fixture
async def make_daemon(tmp_path: Path) -> AsyncIterator[Callable[..., DaemonProcess]]:
    """Build daemon subprocesses on pty pairs; all are killed and closed at the end."""
    made: list[DaemonProcess] = []

    def factory(config: dict[str, Any] | None = None, name: str = "d") -> DaemonProcess:
        directory = tmp_path / f"{name}{len(made)}"
        directory.mkdir()
        daemon = DaemonProcess(directory, config)
        made.append(daemon)
        return daemon

    yield factory
    for daemon in made:
        await daemon.close()
