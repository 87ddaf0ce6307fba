"""Shared fixtures."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.ground.logsetup import reset_logging
from tests.daemonkit import DaemonProcess


@pytest.fixture(autouse=True)
def _fresh_logging() -> Iterator[None]:
    """Commands run in-process configure structlog globally; undo it after each test."""
    yield
    reset_logging()


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
