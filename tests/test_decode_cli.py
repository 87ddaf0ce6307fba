"""`cc-daemon decode`: hex arguments, hex or raw stdin, plain and JSON output, exit status.

Most tests call `cc_daemon.cli.app.main` in-process, with the parser's structlog
events captured (unconfigured, structlog prints them to stdout). A few run the
real command in a subprocess, which is where anything else writing to stdout
(a stray print, an unconfigured logger) would corrupt the JSON lines.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import structlog

from cc_daemon.cli.app import main
from tests.test_protocol_examples import EXAMPLES, MANUAL_P_T, P_G
from tests.waitkit import DEADLINE_S

ROOT = Path(__file__).resolve().parents[1]
P_T_HEX = EXAMPLES["P-T"][0]
MANUAL_HEX = MANUAL_P_T.hex(" ").upper()
EXCHANGE = [EXAMPLES[name][0] for name in ("P-T", "P-M", "R-O", "R-M", "P-S", "R-P", "R-F")]

P_T_JSON = {
    "frame": "P-T",
    "timestamp_s": 72,
    "lon_e7": -37260579,
    "lat_e7": 404506308,
    "alt_mm": 702385,
    "sonar_distance_mm": 8219,
    "sonar_confidence_pct": 100,
}


def run(
    argv: list[str], capsys: pytest.CaptureFixture[str], stdin: bytes | None = None
) -> tuple[int, list[str], str]:
    if stdin is not None:
        sys.stdin = io.TextIOWrapper(io.BytesIO(stdin))
    status = main(["decode", *argv])
    out, err = capsys.readouterr()
    return status, out.splitlines(), err


def json_lines(lines: list[str]) -> list[dict[str, Any]]:
    return [json.loads(line) for line in lines]


def assert_error(obj: dict[str, Any], kind: str, data: str) -> None:
    assert obj["error"] == kind
    assert obj["bytes"] == data
    assert set(obj) <= {"error", "bytes", "detail"}


@pytest.fixture(autouse=True)
def _restore_stdin(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys, "stdin", sys.stdin)  # undone after each test


@pytest.fixture(autouse=True)
def _capture_logs() -> Iterator[None]:
    with structlog.testing.capture_logs():
        yield


# ---------------------------------------------------------------- hex arguments


def test_hex_arguments_plain_output(capsys: pytest.CaptureFixture[str]) -> None:
    status, lines, _ = run(["50", "53", "00", "48", "00", "EB"], capsys)
    assert status == 0
    assert lines == ["P-S timestamp_s=72"]


def test_fault_report_decodes_with_its_depth(capsys: pytest.CaptureFixture[str]) -> None:
    # The bytes the firmware was fed on 53bf5564 (docs/protocol.md): R-L, t=5, 2.5 m.
    status, lines, _ = run(["52", "4C", "00", "05", "09", "C4", "01", "70"], capsys)
    assert status == 0
    assert lines[0].startswith("R-L timestamp_s=5 depth_mm=2500")


def test_position_frame_plain_output_names_fields_and_degrees(
    capsys: pytest.CaptureFixture[str],
) -> None:
    status, lines, _ = run(P_T_HEX.split(), capsys)
    assert status == 0
    assert lines == [
        "P-T timestamp_s=72 lon_e7=-37260579 lat_e7=404506308 alt_mm=702385 "
        "sonar_distance_mm=8219 sonar_confidence_pct=100  (40.4506308, -3.7260579)"
    ]


def test_json_output_of_a_frame(capsys: pytest.CaptureFixture[str]) -> None:
    status, lines, _ = run(["--json", *P_T_HEX.split()], capsys)
    assert status == 0
    assert json_lines(lines) == [P_T_JSON]
    assert lines[0].startswith('{"frame": "P-T", "timestamp_s": 72, "lon_e7": -37260579')


def test_json_output_of_the_whole_exchange(capsys: pytest.CaptureFixture[str]) -> None:
    status, lines, _ = run(["--json", " ".join(EXCHANGE)], capsys)
    assert status == 0
    objs = json_lines(lines)
    assert [obj["frame"] for obj in objs] == ["P-T", "P-M", "R-O", "R-M", "P-S", "R-P", "R-F"]
    assert objs[3] == {"frame": "R-M", "timestamp_s": 72, "depth_mm": 15820}
    assert objs[4] == {"frame": "P-S", "timestamp_s": 72}


@pytest.mark.parametrize(
    "args",
    [
        ["50530048", "00EB"],
        ["0x50,0x53,0x00,0x48,0x00,0xEB"],
        ["50:53:00:48:00:eb"],
    ],
)
def test_hex_argument_spellings(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    status, lines, _ = run(args, capsys)
    assert (status, lines) == (0, ["P-S timestamp_s=72"])


def test_bad_checksum_is_printed_with_its_bytes_and_exit_1(
    capsys: pytest.CaptureFixture[str],
) -> None:
    status, lines, _ = run(["--json", MANUAL_HEX], capsys)
    assert status == 1
    [obj] = json_lines(lines)
    assert_error(obj, "bad_checksum", MANUAL_HEX)


def test_bad_checksum_plain_output(capsys: pytest.CaptureFixture[str]) -> None:
    status, lines, _ = run([MANUAL_HEX], capsys)
    assert status == 1
    assert len(lines) == 1
    assert lines[0].startswith(f"ERROR bad_checksum: {MANUAL_HEX}")


def test_errors_and_frames_come_out_in_stream_order(capsys: pytest.CaptureFixture[str]) -> None:
    bad_field = bytearray(bytes.fromhex(P_T_HEX))
    bad_field[4] = 0x02  # lon sign byte
    bad_field[-2:] = (sum(bad_field[:-2]) % 65536).to_bytes(2, "big")
    stream = (
        EXAMPLES["R-O"][0]
        + " 50 58 "  # P, then type X
        + bad_field.hex(" ")
        + " "
        + EXAMPLES["R-F"][0]
        + " 52 4D 00"  # cut short
    )
    status, lines, _ = run(["--json", stream], capsys)
    assert status == 1
    objs = json_lines(lines)
    assert objs[0] == {"frame": "R-O", "timestamp_s": 72}
    assert_error(objs[1], "unknown_type", "50 58")
    assert_error(objs[2], "bad_field", bad_field.hex(" ").upper())
    assert objs[3] == {"frame": "R-F", "timestamp_s": 72, "depth_mm": 0}
    assert_error(objs[4], "truncated", "52 4D 00")
    assert len(objs) == 5


def test_g_alias_needs_the_flag(capsys: pytest.CaptureFixture[str]) -> None:
    g_hex = P_G.hex(" ")
    status, lines, _ = run(["--json", g_hex], capsys)
    assert status == 1
    assert_error(json_lines(lines)[0], "unknown_type", "50 47")
    status, lines, _ = run(["--json", "--accept-g-alias", g_hex], capsys)
    assert status == 0
    assert json_lines(lines) == [{**P_T_JSON, "frame": "P-M"}]


@pytest.mark.parametrize("args", [["ZZ"], ["505"], ["50", "5x"], ["0x5"]])
def test_non_hex_arguments_exit_2(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    status, lines, err = run(args, capsys)
    assert status == 2
    assert lines == []
    assert "not hex" in err


# ---------------------------------------------------------------- stdin


def test_hex_text_on_stdin(capsys: pytest.CaptureFixture[str]) -> None:
    text = "\n".join(EXCHANGE[:3]) + "\n\n" + MANUAL_HEX + "\n"
    status, lines, _ = run(["--hex", "--json"], capsys, stdin=text.encode())
    assert status == 1
    objs = json_lines(lines)
    assert [obj.get("frame", obj.get("error")) for obj in objs] == [
        "P-T",
        "P-M",
        "R-O",
        "bad_checksum",
    ]


def test_hex_stdin_frames_may_span_lines(capsys: pytest.CaptureFixture[str]) -> None:
    text = "50 53 00\n48 00 EB\n"
    status, lines, _ = run(["--hex"], capsys, stdin=text.encode())
    assert (status, lines) == (0, ["P-S timestamp_s=72"])


def test_non_hex_text_on_stdin_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    status, _, err = run(["--hex"], capsys, stdin=b"50 53 00 48 00 EB\nhello\n")
    assert status == 2
    assert "not hex" in err


def test_raw_bytes_on_stdin(capsys: pytest.CaptureFixture[str]) -> None:
    raw = b"".join(bytes.fromhex(h) for h in EXCHANGE) + b"\x00\xff" + MANUAL_P_T
    status, lines, _ = run(["--json"], capsys, stdin=raw)
    assert status == 1
    objs = json_lines(lines)
    assert len(objs) == 8
    assert objs[0] == P_T_JSON
    assert_error(objs[-1], "bad_checksum", MANUAL_HEX)


def test_clean_raw_stdin_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    raw = b"".join(bytes.fromhex(h) for h in EXCHANGE) * 50
    status, lines, _ = run([], capsys, stdin=raw)
    assert status == 0
    assert len(lines) == 350


def test_raw_stdin_ending_mid_frame_reports_truncated(capsys: pytest.CaptureFixture[str]) -> None:
    raw = bytes.fromhex(EXAMPLES["R-O"][0]) + bytes.fromhex(P_T_HEX)[:10]
    status, lines, _ = run(["--json"], capsys, stdin=raw)
    assert status == 1
    objs = json_lines(lines)
    assert objs[0] == {"frame": "R-O", "timestamp_s": 72}
    assert_error(objs[1], "truncated", bytes.fromhex(P_T_HEX)[:10].hex(" ").upper())


def test_empty_stdin_is_clean(capsys: pytest.CaptureFixture[str]) -> None:
    summary = "# 0 frames, 0 errors (0 bad checksum, 0 unknown type, 0 bad field, 0 truncated)"
    assert run([], capsys, stdin=b"") == (0, [], f"{summary}, 0 bytes skipped\n")


# ---------------------------------------------------------------- the real command


def cc_daemon(*args: str, stdin: bytes) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(
        [sys.executable, "-m", "cc_daemon", "decode", *args],
        input=stdin,
        capture_output=True,
        cwd=ROOT,
        timeout=DEADLINE_S,
        check=False,
    )


SUBPROCESS_ERRORS = "\n".join([*EXCHANGE, MANUAL_HEX, "52 4F"]) + "\n"


def test_subprocess_errors_are_printed_and_exit_1() -> None:
    done = cc_daemon("--hex", "--json", stdin=SUBPROCESS_ERRORS.encode())
    assert done.returncode == 1, done.stderr
    lines = [line for line in done.stdout.decode().splitlines() if line.startswith("{")]
    objs = [json.loads(line) for line in lines]
    assert [obj.get("frame", obj.get("error")) for obj in objs] == [
        "P-T",
        "P-M",
        "R-O",
        "R-M",
        "P-S",
        "R-P",
        "R-F",
        "bad_checksum",
        "truncated",
    ]
    assert objs[0] == P_T_JSON
    assert_error(objs[7], "bad_checksum", MANUAL_HEX)
    assert_error(objs[8], "truncated", "52 4F")


def test_subprocess_json_output_is_only_json_lines() -> None:
    done = cc_daemon("--hex", "--json", stdin=SUBPROCESS_ERRORS.encode())
    objs = [json.loads(line) for line in done.stdout.decode().splitlines()]  # every line is JSON
    assert [obj.get("frame", obj.get("error")) for obj in objs] == [
        "P-T",
        "P-M",
        "R-O",
        "R-M",
        "P-S",
        "R-P",
        "R-F",
        "bad_checksum",
        "truncated",
    ]
    assert done.returncode == 1


def test_subprocess_raw_capture_clean_exits_0() -> None:
    raw = b"".join(bytes.fromhex(h) for h in EXCHANGE)
    done = cc_daemon(stdin=raw)
    assert done.returncode == 0, done.stderr
    assert done.stdout.decode().splitlines()[4] == "P-S timestamp_s=72"
    assert len(done.stdout.decode().splitlines()) == 7


def test_subprocess_non_hex_exits_2() -> None:
    done = cc_daemon("50", "ZZ", stdin=b"")
    assert done.returncode == 2
    assert done.stdout == b""
    assert b"not hex" in done.stderr


def test_at_a_terminal_decode_says_what_it_waits_for_and_ctrl_c_is_quiet() -> None:
    import os
    import signal
    import subprocess
    import sys

    from tests.daemonkit import REPO

    for stop in ("ctrl-d", "ctrl-c"):
        master, slave = os.openpty()  # a terminal in its cooked mode: Ctrl-D is end of input
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "cc_daemon", "decode"],
                stdin=slave,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                env={**os.environ, "PYTHONPATH": str(REPO)},
            )
            assert proc.stderr is not None
            prompt = proc.stderr.readline().decode()
            assert prompt == (
                "cc-daemon decode: reading hex or bytes from standard input "
                "(Ctrl-D to end, Ctrl-C to stop)\n"
            )
            if stop == "ctrl-d":
                os.write(master, b"\x04")
            else:  # the prompt is out: decode is reading, with its own Ctrl-C back
                proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=DEADLINE_S)
        finally:
            if proc.poll() is None:  # a failure above: never into the next test
                proc.kill()
                proc.communicate()
            os.close(master)
            os.close(slave)
        assert b"Traceback" not in err, err
        assert proc.returncode == (0 if stop == "ctrl-d" else 130), err
