"""A command whose output cannot be written: one line on stderr, exit 74, never a traceback.

Real processes writing to /dev/full (every write fails with ENOSPC, as on a
full disk), and the rule in-process: an error from elsewhere is not taken for
the output's, and a reader leaving a pipe is not an error.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cc_daemon.cli.output import EXIT_OUTPUT, guarded

ROOT = Path(__file__).resolve().parents[1]
FULL = Path("/dev/full")
FRAME = "425200aa0000ffffffff0000000000000000000000000000004c"


def cc_daemon(*args: str, stdin: bytes = b"") -> subprocess.CompletedProcess[bytes]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    with FULL.open("wb") as full:
        return subprocess.run(
            [sys.executable, "-m", "cc_daemon", *args],
            input=stdin, stdout=full, stderr=subprocess.PIPE, env=env, timeout=60, check=False,
        )  # fmt: skip


@pytest.mark.skipif(not FULL.exists(), reason="no /dev/full")
@pytest.mark.parametrize(
    ("args", "stdin"),
    [
        (("decode", FRAME), b""),
        (("decode", "--json", FRAME), b""),
        (("decode", "--hex"), FRAME.encode() + b"\n"),
        (("doctor",), b""),
        (("doctor", "--json"), b""),
        (("--version",), b""),
    ],
    ids=["decode_hex", "decode_json", "decode_stdin", "doctor", "doctor_json", "version"],
)
def test_output_to_a_full_device_is_one_line_and_exit_74(
    args: tuple[str, ...], stdin: bytes
) -> None:
    done = cc_daemon(*args, stdin=stdin)
    err = done.stderr.decode()
    assert done.returncode == EXIT_OUTPUT, err
    assert err.endswith("cc-daemon: cannot write the output: No space left on device\n"), err
    assert "Traceback" not in err and "Exception ignored" not in err


def test_an_error_from_elsewhere_is_not_the_outputs() -> None:
    def journal_fails() -> int:
        raise OSError(errno.ENOSPC, "No space left on device", "j.db")

    with pytest.raises(OSError, match=r"j\.db"):
        guarded(journal_fails)


def test_a_reader_that_leaves_is_not_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    class Gone:
        def write(self, text: str) -> int:
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

        def flush(self) -> None:
            pass

        def fileno(self) -> int:
            return 1

    monkeypatch.setattr(sys, "stdout", Gone())
    monkeypatch.setattr("cc_daemon.cli.output._silence_stdout", lambda: None)

    def prints() -> int:
        print("a line")
        return 0

    assert guarded(prints) == 0
