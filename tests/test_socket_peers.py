"""The sockets against other users (issue 27): impostors, outsiders and floods.

Real second users (made with useradd, as root; skipped with a message where
they cannot be made), real sockets, the real commands run as those users
(`tests/as_user.py`) and a real daemon, in-process or as a subprocess.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
import structlog

from cc_daemon.cli.app import main
from cc_daemon.config import Settings
from cc_daemon.daemon.service import Daemon
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from tests.daemonkit import FAST_CAST, DaemonProcess, merge, toml_text
from tests.peerkit import (
    REPO,
    User,
    Users,
    acting,
    as_user,
    entered_dir,
    session_users,
)

FAKE_STATUS = json.dumps({"daemon": {"pid": 1}, "cast": {"phase": "idle", "depth_m": 0.0}})
FAKE_RELEASE = json.dumps({"ok": True, "message": "station released: R-F sent (cast 1)"})


@pytest.fixture(scope="session")
def users() -> Iterator[Users]:
    with session_users() as made:
        yield made


@pytest.fixture
def open_dir() -> Iterator[Path]:
    with entered_dir() as path:
        yield path


@pytest.fixture
def mallory(users: Users) -> User:
    return users.user("m")


@contextlib.contextmanager
def impostor(user: User, path: Path, text: str) -> Iterator[None]:
    """`user` answering every connection on `path` with `text`."""
    with acting(user, "serve", str(path), text):
        yield


@contextlib.asynccontextmanager
async def daemon_in_process(tmp_path: Path, extra: dict[str, Any]) -> AsyncIterator[Daemon]:
    with PtyPair(tmp_path / "tty") as pty:
        config = merge(merge(FAST_CAST, {"serial": {"port": str(pty.path)}}), extra)
        daemon = Daemon(Settings.model_validate(config))
        port = await FramePort.over_fd(pty.master_fd)
        task = asyncio.create_task(daemon.run())
        try:
            await asyncio.wait_for(daemon.ready.wait(), 10)
            yield daemon
        finally:
            daemon.request_shutdown()
            assert await asyncio.wait_for(task, 10) == 0
            await port.close()


async def wait_for(path: Path) -> None:
    deadline = time.monotonic() + 30
    while not await asyncio.to_thread(path.exists):
        assert time.monotonic() < deadline, f"{path} never appeared"
        await asyncio.sleep(0.02)


async def cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = await asyncio.to_thread(main, args)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


async def test_status_and_release_believe_only_the_daemon(
    mallory: User, open_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A directory root owns that mallory's group may write (not world-writable):
    # mallory binds sockets there that answer like a daemon.
    box = open_dir / "box"
    box.mkdir()
    os.chown(box, 0, mallory.gid)
    box.chmod(0o775)
    with impostor(mallory, box / "status.sock", FAKE_STATUS):
        code, out, err = await cli(["status", "--socket", str(box / "status.sock")], capsys)
        assert code == 1 and out == ""
        assert f"refusing {box / 'status.sock'}: it is answered by uid {mallory.uid}" in err
        assert err.count("\n") == 1
    with impostor(mallory, box / "control.sock", FAKE_RELEASE):
        args = ["release", "--reason", "seen on deck", "--socket", str(box / "control.sock")]
        code, out, err = await cli(args, capsys)
        assert code == 1 and "released" not in out
        assert f"answered by uid {mallory.uid}" in err and "nothing was released" in err


async def test_a_daemon_by_hand_with_its_journal_in_tmp_serves_in_its_private_directory(
    mallory: User,
    open_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # docs/simulator.md: `cc-daemon --port ... --db /tmp/bench-test.db`. Another user
    # has bound the sockets beside that journal first.
    shared = open_dir / "tmp"
    shared.mkdir()
    shared.chmod(0o1777)
    journal = shared / "bench-test.db"
    runtime = open_dir / "run-user"  # short: the socket is named after the journal
    runtime.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    with (
        impostor(mallory, Path(f"{journal}.status.sock"), FAKE_STATUS),
        impostor(mallory, Path(f"{journal}.control.sock"), FAKE_RELEASE),
        structlog.testing.capture_logs() as logs,
    ):
        async with daemon_in_process(tmp_path, {"store": {"path": str(journal)}}):
            private = runtime / "cc-daemon"
            await wait_for(private)
            deadline = time.monotonic() + 30
            while not await asyncio.to_thread(lambda: len(list(private.glob("*.sock"))) == 2):
                assert time.monotonic() < deadline, list(private.iterdir())
                await asyncio.sleep(0.02)
            assert private.stat().st_mode & 0o777 == 0o700
            from cc_daemon.config.statuspaths import private_socket

            assert private_socket(journal).is_socket()  # named after the journal
            code, out, err = await cli(["status", "--json", "--db", str(journal)], capsys)
            assert code == 0, err
            document = json.loads(out.strip().splitlines()[-1])
            assert document["daemon"]["pid"] == os.getpid()  # the daemon, not the impostor
            args = ["release", "--reason", "x", "--db", str(journal)]
            code, out, err = await cli(args, capsys)
            assert (code, out.strip()) == (1, "cc-daemon release: no stranded station to release")
            # The impostor's sockets are refused, not asked.
            args = ["status", "--socket", f"{journal}.status.sock"]
            code, out, err = await cli(args, capsys)
            assert code == 1 and f"{shared} may be written by every user" in err
    said = [e["event"] for e in logs if "status socket not beside" in str(e.get("event"))]
    assert len(said) == 1 and f"{shared} may be written by every user" in said[0]
    assert not any("another process answers" in str(e.get("error", "")) for e in logs)


async def test_a_user_outside_the_group_gets_one_line_and_the_winch_is_not_driven(
    mallory: User, open_dir: Path, tmp_path: Path
) -> None:
    # The service's directory is 0750: mallory, outside its group, may not enter it.
    service = open_dir / "run"
    service.mkdir(mode=0o750)
    config = open_dir / "cc-daemon.toml"
    config.write_text(f'[status]\npath = "{service / "status.sock"}"\n')
    config.chmod(0o644)
    extra = {
        "store": {"path": str(tmp_path / "j.db")},
        "status": {"path": str(service / "status.sock")},
    }
    async with daemon_in_process(tmp_path, extra):
        await wait_for(service / "control.sock")
        for args in (
            ["status", "--config", str(config)],
            ["release", "--reason", "seen on deck", "--config", str(config)],
            ["--watch-drum", "winch", "home", "--mock", "--config", str(config)],
        ):
            done = await asyncio.to_thread(as_user, mallory, "cli", *args)
            said = [line for line in done.stderr.splitlines() if not line.startswith("drum: ")]
            assert done.returncode == 1, (args, done.stdout, done.stderr)
            assert len(said) == 1 and "not authorised" in said[0], (args, done.stderr)
            assert "Traceback" not in done.stderr and done.stdout == ""
            if "winch" in args:
                drum = json.loads(done.stderr.split("drum: ")[1])
                assert drum == {"built": False, "motor_ran": False}  # never a second driver
    # Without a daemon (nothing at the path), the same command drives the mock winch
    # itself: the test can see a winch driven.
    (open_dir / "empty").mkdir(mode=0o755)
    config.write_text(f'[status]\npath = "{open_dir / "empty" / "status.sock"}"\n')
    home = ("--watch-drum", "winch", "home", "--mock", "--config", str(config))
    done = await asyncio.to_thread(as_user, mallory, "cli", *home)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stderr.split("drum: ")[1])["built"] is True


async def test_a_refusal_always_reads_not_authorised(
    mallory: User, open_dir: Path, tmp_path: Path
) -> None:
    # The socket made reachable to mallory (0666): the daemon's own check refuses
    # her, every time, and the command says so, never "Broken pipe" (no daemon).
    extra = {
        "store": {"path": str(tmp_path / "j.db")},
        "status": {"path": str(open_dir / "status.sock")},
    }
    async with daemon_in_process(tmp_path, extra):
        control = open_dir / "control.sock"
        await wait_for(control)
        control.chmod(0o666)
        args = ("--times", "20", "release", "--reason", "x", "--socket", str(control))
        done = await asyncio.to_thread(as_user, mallory, "cli", *args)
        assert done.returncode == 0, done.stderr
        runs = json.loads(done.stdout)
    assert [code for code, _ in runs] == [1] * 20, runs
    assert all("not authorised" in output for _, output in runs), runs


GROUPS_WITHOUT_DESCRIPTORS = textwrap.dedent(
    """
    import json, os, resource, socket, struct, sys, tempfile
    from cc_daemon.daemon.control_server import Peer, authorised
    try:
        from cc_daemon.ground.peercred import peer_groups
        check = lambda peer, conn: authorised(peer, group, peer_groups(conn))
    except ImportError:  # before issue 27: the groups by name
        check = lambda peer, conn: authorised(peer, group)

    uid, gid, group = (int(a) for a in sys.argv[1:4])
    top = tempfile.mkdtemp()
    os.chmod(top, 0o755)
    path = os.path.join(top, "c.sock")
    server = socket.socket(socket.AF_UNIX)
    server.bind(path)
    os.chmod(path, 0o666)
    server.listen(1)
    child = os.fork()
    if child == 0:
        os.setgroups([group]); os.setgid(gid); os.setuid(uid)
        client = socket.socket(socket.AF_UNIX)
        client.connect(path)
        client.recv(1)
        os._exit(0)
    conn, _ = server.accept()
    lowest = os.dup(0)
    os.close(lowest)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (lowest, hard))  # not one more
    try:
        try:
            os.dup(0)
            full = False
        except OSError:
            full = True
        raw = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, 12)
        peer = Peer(*struct.unpack("3i", raw))
        ok = check(peer, conn)
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    conn.close()
    os.waitpid(child, 0)
    os.unlink(path)
    os.rmdir(top)
    print(json.dumps({"full": full, "authorised": ok, "uid": peer.uid}))
    """
)


def test_a_member_is_authorised_with_no_descriptor_to_spare(users: Users) -> None:
    # A member listed in /etc/group only by name: today's look-up by name needs a
    # descriptor (/etc/passwd, /etc/group); the kernel's SO_PEERGROUPS does not.
    group = users.group("g")
    member = users.user("g1", groups=(group,))
    done = subprocess.run(
        [sys.executable, "-c", GROUPS_WITHOUT_DESCRIPTORS, str(member.uid), str(member.gid),
         str(group)],
        capture_output=True, text=True, check=False, timeout=30,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == {"full": True, "authorised": True, "uid": member.uid}


RLIMIT_1024 = (
    "import os, resource, sys; resource.setrlimit(resource.RLIMIT_NOFILE, (1024, 1024));"
    " os.execv(sys.argv[1], sys.argv[1:])"
)


def descriptors(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


@contextlib.contextmanager
def holding(user: User, path: Path, count: int) -> Iterator[int]:
    """`user` holding `count` connections to `path` (those that connected: yielded)."""
    with acting(user, "hold", str(path), str(count)) as ready:
        yield int(ready.split()[1])


class PeakDescriptors:
    """The most descriptors a process had open, sampled every 5 ms in a thread."""

    def __init__(self, pid: int) -> None:
        self._pid = pid
        self.peak = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.005):
            with contextlib.suppress(OSError):
                self.peak = max(self.peak, descriptors(self._pid))

    def __enter__(self) -> PeakDescriptors:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()


@pytest.mark.slow
@pytest.mark.timeout(120)  # the control socket accepts 100 a second: 11 s of holding alone
async def test_a_member_holding_1100_connections_takes_no_descriptor_the_daemon_needs(
    users: Users, open_dir: Path, tmp_path: Path
) -> None:
    group = users.group("o")
    attacker = users.user("o1", groups=(group,))
    member = users.user("o2", groups=(group,))
    service = open_dir / "run"
    service.mkdir()
    os.chown(service, 0, group)
    service.chmod(0o2750)  # setgid: the sockets are the operators' group's
    control, status = service / "control.sock", service / "status.sock"
    daemon = DaemonProcess(tmp_path, {"status": {"path": str(status)}})
    daemon.config_path.write_text(toml_text(daemon.config))
    try:
        daemon.start(prefix=[sys.executable, "-c", RLIMIT_1024])  # systemd's default
        await daemon.connect()
        await daemon.wait_answering()
        await wait_for(control)
        assert daemon.proc is not None
        pid = daemon.proc.pid
        with (
            PeakDescriptors(pid) as peak,
            holding(attacker, control, 1100) as on_control,
            holding(attacker, status, 1100) as on_status,
        ):
            assert (on_control, on_status) == (1100, 1100)
            release = ("release", "--reason", "x", "--socket", str(control))
            done = await asyncio.to_thread(as_user, member, "cli", *release)
            asked = ("status", "--json", "--socket", str(status))
            read = await asyncio.to_thread(as_user, member, "cli", *asked)
            await daemon.wait_answering(timeout=5)  # the autopilot is still answered
        # The daemon kept its reserve whatever the attacker held.
        assert peak.peak <= 1024 - 64, (peak.peak, daemon.log_text()[-2000:])
        assert done.stdout.strip() == "cc-daemon release: no stranded station to release", (
            done.stdout + done.stderr
        )
        assert read.returncode == 0 and json.loads(read.stdout)["daemon"]["pid"] == pid
        daemon.check_alive()
        # What the log said of the flood: counted, not a line per connection.
        refused = [e for e in daemon.log_events() if "connection refused" in e.get("event", "")]
        assert 1 <= len(refused) <= 10, len(refused)
    finally:
        await daemon.close()
