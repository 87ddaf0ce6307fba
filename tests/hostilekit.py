"""Test kit for hostile journals: the real command line in a child process, bounded.

A hostile file can hang a reader (a FIFO, an endless view) or eat its memory
(`/dev/zero`): the commands run in a child process with an address-space cap
(1.5 GiB: a data command needs under 300 MB) and a deadline, so a hang or a
runaway fails its test in a couple of minutes instead of taking the machine or the
suite's per-test backstop. One child runs a list of commands in turn, each as
`cc-daemon` runs it (`cli.app.main`), and reports each one's exit status,
output and errors as JSON.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
# A child that has not answered by then hangs: the test fails. Its sixteen commands
# take a few seconds on an idle machine, well over 25 s on a loaded one (seen at
# load 24); a hang is for ever, so the margin costs only a failing run's time.
HANG_S = 150.0
MEMORY_CAP = 3 << 29  # 1.5 GiB of address space

_DRIVER = r"""
import contextlib, io, json, sys, traceback
{setup}
from cc_daemon.cli.app import main
results = []
for argv in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
        except BaseException:
            traceback.print_exc(file=err)
            code = "raised"
    text = out.getvalue()
    results.append({{"code": code, "stdout": text[:20000], "stdout_chars": len(text),
                     "stderr": err.getvalue()[-20000:]}})
print(json.dumps(results))
"""


@dataclass(frozen=True)
class Answer:
    code: int | str
    stdout: str
    stdout_chars: int
    stderr: str

    @property
    def said(self) -> list[str]:
        """The command's own lines on stderr (`cc-daemon NAME: ...`)."""
        return [line for line in self.stderr.splitlines() if line.startswith("cc-daemon ")]

    def one_clear_line(self) -> str:
        """The one line that says what is wrong (asserting there is one and no traceback)."""
        assert "Traceback" not in self.stderr, self.stderr
        assert self.code == 1, (self.code, self.stderr)
        assert len(self.said) == 1, self.stderr
        return self.said[0]


def _cap() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))


def run_commands(
    *argvs: list[str],
    setup: str = "",
    timeout: float = HANG_S,
    env: dict[str, str] | None = None,
) -> list[Answer]:
    """Run each argv as `cc-daemon ARGV` in one child process; `setup` is Python run in
    the child first (e.g. a smaller time bound). Fails the test if the child hangs."""
    done = subprocess.run(
        [sys.executable, "-c", _DRIVER.format(setup=setup), json.dumps(list(argvs))],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        cwd=REPO,
        env={**os.environ, **(env or {})},
        preexec_fn=_cap,
    )
    assert done.returncode == 0, done.stderr[-5000:]
    return [Answer(**r) for r in json.loads(done.stdout)]


def run_command(*argv: str, **options: object) -> Answer:
    return run_commands(list(argv), **options)[0]  # type: ignore[arg-type]
