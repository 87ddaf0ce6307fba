"""`cc-daemon decode` on everyday input: pipes, hex without --hex, a summary, stray options,
and a port another process is reading."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import structlog

from cc_daemon.cli.app import main
from cc_daemon.cli.decode import looks_like_hex
from tests.daemonkit import REPO
from tests.test_live_decode_and_systemd import _read_lines
from tests.test_protocol_examples import EXAMPLES
from tests.waitkit import DEADLINE_S

EXCHANGE = b"".join(
    bytes.fromhex(EXAMPLES[name][0]) for name in ("P-T", "P-M", "R-O", "R-M", "P-S", "R-P", "R-F")
)


@pytest.fixture(autouse=True)
def _quiet(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "stdin", sys.stdin)  # undone after each test
    structlog.reset_defaults()


def run(
    argv: list[str], capsys: pytest.CaptureFixture[str], stdin: bytes = b""
) -> tuple[int, str, str]:
    sys.stdin = io.TextIOWrapper(io.BytesIO(stdin))
    status = main(argv)
    out, err = capsys.readouterr()
    return status, out, err


def cc_daemon(*args: str, **kwargs: object) -> subprocess.Popen[bytes]:
    return subprocess.Popen(  # type: ignore[call-overload, no-any-return]
        [sys.executable, "-m", "cc_daemon", *args],
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        **kwargs,
    )


def test_every_decode_ends_with_a_summary_line(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = run(["decode"], capsys, stdin=EXCHANGE + b"\x00\x00PS")
    assert status == 1  # the truncated P-S at the end
    assert len(out.splitlines()) == 8
    assert err.splitlines()[-1] == (
        "# 7 frames, 1 errors (0 bad checksum, 0 unknown type, 0 bad field, 1 truncated), "
        "4 bytes skipped"
    )
    status, _, err = run(["decode", "50", "53", "00", "48", "00", "EB"], capsys)
    assert (status, err.splitlines()[-1][:10]) == (0, "# 1 frames")


@pytest.mark.parametrize(
    "text",
    [b"50 53 00 48 00 EB\n", b"0x50,0x53,0x00\n", b"505300480 0EB", b"5053004800EB\n" * 2000],
)
def test_hex_text_on_stdin_without_hex_is_pointed_at_hex(
    capsys: pytest.CaptureFixture[str], text: bytes
) -> None:
    status, out, err = run(["decode"], capsys, stdin=text)
    assert (status, out) == (2, "")
    assert err.splitlines()[-1] == (
        f"cc-daemon decode: 0 frames in {len(text)} bytes; this looks like hex text: use --hex"
    )


def test_what_is_not_hex_text() -> None:
    assert not looks_like_hex(b"")
    assert not looks_like_hex(b"hello world")
    assert not looks_like_hex(EXCHANGE)
    assert not looks_like_hex(b"\x00\x01\x02\x03")
    assert looks_like_hex(b"50 53\r\n00 48\r\n")


def test_binary_that_decodes_to_nothing_is_not_called_hex(
    capsys: pytest.CaptureFixture[str],
) -> None:
    status, out, err = run(["decode"], capsys, stdin=b"\x00\x01\x02garbage")
    assert (status, out) == (0, "")
    assert "use --hex" not in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["decode", "50", "53", "--port", "/dev/ttyX"], "hex arguments and --port"),
        (["decode", "--hex", "--port", "/dev/ttyX"], "--hex reads stdin"),
        (["decode", "--baudrate", "19200"], "--baudrate applies only with --port"),
        (["decode", "--shared"], "--shared applies only with --port"),
        (["decode", "--hex", "50"], "--hex reads hex text from stdin"),
        (["--winch-stall"], "--winch-stall applies only with --simulate"),
        (["--corrupt", "0.1", "decode"], "--corrupt applies only with --simulate"),
    ],
)
def test_options_that_do_not_apply_are_refused(
    capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    status, out, err = run(argv, capsys)
    assert (status, out) == (2, "")
    assert message in err


def test_decode_baudrate_is_validated_as_the_daemons(capsys: pytest.CaptureFixture[str]) -> None:
    status, _, err = run(["decode", "--port", "/dev/ttyX", "--baudrate", "9601"], capsys)
    daemon_status, _, daemon_err = run(["--baudrate", "9601"], capsys)
    assert status == daemon_status == 2
    assert err == daemon_err
    assert err.startswith("cc-daemon: bad configuration: serial.baudrate = 9601 (from --baudrate):")


@pytest.mark.slow
def test_a_closed_pipe_ends_decode_quietly(tmp_path: Path) -> None:
    capture = tmp_path / "capture.bin"
    capture.write_bytes(EXCHANGE * 5000)  # 35,000 lines: far more than a pipe holds
    with capture.open("rb") as stdin:
        proc = cc_daemon("decode", stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        assert proc.stdout is not None and proc.stderr is not None
        assert proc.stdout.readline().startswith(b"P-T ")  # `| head -1`
        proc.stdout.close()
        err = proc.stderr.read().decode()
        proc.stderr.close()
        assert proc.wait(DEADLINE_S) == 0, err
    assert "Traceback" not in err and "BrokenPipe" not in err


@pytest.mark.slow
def test_decode_port_refuses_a_port_another_process_has_open(tmp_path: Path) -> None:
    master, slave = os.openpty()  # this process holds the slave: "the daemon"
    try:
        done = subprocess.run(
            [sys.executable, "-m", "cc_daemon", "decode", "--port", os.ttyname(slave)],
            env=dict(os.environ, PYTHONPATH=str(REPO)),
            capture_output=True,
            text=True,
            timeout=DEADLINE_S,
            check=False,
        )
    finally:
        os.close(slave)
        os.close(master)
    assert done.returncode == 2
    assert f"is open in another process: pid {os.getpid()} (" in done.stderr
    assert "--shared" in done.stderr and "second UART" in done.stderr


@pytest.mark.slow
def test_decode_port_reads_a_port_nobody_else_has_open() -> None:
    master, slave = os.openpty()
    name = os.ttyname(slave)
    os.close(slave)  # nobody holds the slave: the master alone keeps it alive
    proc = cc_daemon("decode", "--port", name, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stderr is not None
        # Said once its Ctrl-C handler is in place (`live_decode`): no need to wait more.
        assert any("open" in line for line in _read_lines(proc.stderr, 1, DEADLINE_S))
        proc.send_signal(signal.SIGINT)
        assert proc.wait(DEADLINE_S) == 0
        assert proc.stderr.read().decode().startswith("# 0 frames, 0 errors")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
        os.close(master)
