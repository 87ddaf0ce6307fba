"""`cc-daemon status --config FILE` finds a daemon started by hand with the same file.

The rule (`config.statuspaths`) is pure and tested on its own; then a real
daemon (in-process, on a real pty, with a real journal) started with no
`status.path` and outside systemd serves its socket where the rule says, and
the status command, given only the same configuration file, reads it.
"""

from __future__ import annotations

import asyncio
import json
import os
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.app import main
from cc_daemon.config import Settings, StatusSettings
from cc_daemon.config.statuspaths import (
    SERVICE_SOCKET,
    client_socket_paths,
    daemon_socket_path,
    hand_socket_path,
)
from cc_daemon.daemon.service import Daemon
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import FAST_CAST, merge, toml_text
from tests.waitkit import DEADLINE_S, until

NONE = StatusSettings()


def test_the_rule() -> None:
    configured = StatusSettings(path=Path("/tmp/x.sock"))
    assert daemon_socket_path(configured, {"RUNTIME_DIRECTORY": "/run/a"}) == Path("/tmp/x.sock")
    assert client_socket_paths(configured, {}) == [Path("/tmp/x.sock")]
    # Under systemd: the unit's runtime directory (the first of several).
    assert daemon_socket_path(NONE, {"RUNTIME_DIRECTORY": "/run/cc-daemon:/run/b"}) == (
        SERVICE_SOCKET
    )
    # By hand, with a journal: beside it, whatever XDG_RUNTIME_DIR says.
    env = {"XDG_RUNTIME_DIR": "/run/user/1000"}
    journal = Path("/data/survey.db")
    assert daemon_socket_path(NONE, env, journal) == Path("/data/survey.db.status.sock")
    # By hand, no journal configured: the user's runtime directory.
    assert daemon_socket_path(NONE, env) == Path("/run/user/1000/cc-daemon/status.sock")
    # No runtime directory either: beside the default journal, in the working directory.
    assert daemon_socket_path(NONE, {}) == Path.cwd() / "cc-daemon.db.status.sock"
    # A journal path too long for a Unix socket: the next rule.
    deep = Path("/" + "d" * 120) / "j.db"
    assert hand_socket_path(deep, env) == Path("/run/user/1000/cc-daemon/status.sock")
    # A tool asks the by-hand path first, then the service's.
    assert client_socket_paths(NONE, env, journal) == [
        Path("/data/survey.db.status.sock"), SERVICE_SOCKET,
    ]  # fmt: skip


@pytest.fixture
async def by_hand(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> AsyncIterator[Callable[[dict[str, Any]], Any]]:
    monkeypatch.delenv("RUNTIME_DIRECTORY", raising=False)
    started: list[tuple[Daemon, asyncio.Task[int], FramePort, PtyPair]] = []

    async def start(extra: dict[str, Any]) -> Path:
        pty = PtyPair(tmp_path / "tty")
        config = merge(merge(FAST_CAST, {"serial": {"port": str(pty.path)}}), extra)
        config_path = tmp_path / "cc-daemon.toml"
        config_path.write_text(toml_text(config))
        daemon = Daemon(Settings.model_validate(config))
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        started.append((daemon, task, port, pty))
        await asyncio.wait_for(daemon.ready.wait(), DEADLINE_S)
        return config_path

    yield start
    for daemon, task, port, pty in started:
        daemon.request_shutdown()
        assert await asyncio.wait_for(task, DEADLINE_S) == 0
        await port.close()
        pty.close()


async def _status(config: Path, socket: Path) -> int:
    """`cc-daemon status --config`, once the daemon serves `socket` (bound just after it
    is ready; looked at on the loop that serves it: once there, it is listening too)."""
    await until(socket.is_socket, f"the status socket at {socket}")
    return await asyncio.to_thread(main, ["status", "--json", "--config", str(config)])


async def test_status_finds_a_daemon_started_by_hand_beside_its_journal(
    by_hand: Callable[[dict[str, Any]], Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    journal = tmp_path / "survey.db"
    config = await by_hand({"store": {"path": str(journal)}})
    code = await _status(config, tmp_path / "survey.db.status.sock")
    assert code == 0, capsys.readouterr().err
    document = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert document["link"]["port"] == str(tmp_path / "tty")


async def test_status_finds_a_daemon_in_the_users_runtime_directory(
    by_hand: Callable[[dict[str, Any]], Any],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    runtime = tmp_path / "run-user"
    runtime.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    monkeypatch.chdir(tmp_path)  # no store.path: the journal is ./cc-daemon.db
    config = await by_hand({})
    sock = runtime / "cc-daemon" / "status.sock"
    code = await _status(config, sock)
    assert code == 0, capsys.readouterr().err
    assert (sock.parent.stat().st_mode & 0o777) == 0o700


async def test_no_daemon_names_every_place_it_looked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "c.toml"
    config.write_text(f'[store]\npath = "{tmp_path / "j.db"}"\n')
    assert main(["status", "--config", str(config)]) == 1
    err = capsys.readouterr().err
    assert str(SERVICE_SOCKET) in err and f"{tmp_path / 'j.db'}.status.sock" in err
    assert err.count("\n") == 1
    assert os.fspath(tmp_path) in err
