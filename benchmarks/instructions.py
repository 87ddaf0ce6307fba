"""The daemon's start counted in instructions: exec -> first R-P under valgrind.

Wall and CPU times of a 0.3 s start move by a third from minute to minute on a
shared machine; the instructions a start executes do not (two runs of the same
tree agree within about 0.2 %, the hash seed's doing). Each tree given (default:
this one) is started as `benchmarks.goals` starts it (the shipped configuration,
`--winch sim`, a JSON log, on a pty, bytecode cached) under `valgrind
--tool=callgrind`, through a wrapper that ends the process the moment it has
written its first `R-P` (and lets the daemon's signal handlers be, where valgrind
keeps a real-time signal for itself). Needs valgrind; about 20 s a tree.

`--libraries` counts, for scale, a bare interpreter importing the libraries
every daemon needs, as the daemon imports them (asyncio without ssl, structlog
without rich, pydantic with a model's validator, sqlite3, pyserial, tomllib,
argparse, ctypes) and nothing of ours: the part of a start no change of ours
can remove.

    python -m benchmarks.instructions [TREE ...]     (TREE: another checkout)
    python -m benchmarks.instructions --libraries
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.daemon import wait_first_answer
from benchmarks.goals import REPO, daemon_command, daemon_env, warm_bytecode
from cc_daemon.sim.pty import PtyPair

# Run as `python WRAPPER ARGS...`: the daemon as `python -m cc_daemon ARGS...`, ended
# (os._exit, no clean-up counted) by its first R-P.
WRAPPER = """
import os, signal, sys
sys.argv = ["cc_daemon", *sys.argv[1:]]
sys.path.pop(0)
write = os.write
def first_rp_ends_it(fd, data):
    done = write(fd, data)
    if bytes(data[:2]) == b"RP":
        os._exit(0)
    return done
os.write = first_rp_ends_it
install = signal.signal
def tolerant(signum, handler):
    try:
        return install(signum, handler)
    except OSError:
        return signal.SIG_DFL
signal.signal = tolerant
from cc_daemon.__main__ import main
main()
"""


LIBRARIES = """
import os, sys
sys.modules["ssl"] = None
import asyncio
del sys.modules["ssl"]
sys.modules["rich"] = None
import structlog
del sys.modules["rich"]
import argparse, ctypes, json, pathlib, socket, sqlite3, tomllib
import serial
from cc_daemon.ground.leanimports import pydantic_without_plugins
with pydantic_without_plugins():
    from pydantic import BaseModel, Field
    class One(BaseModel):
        x: int = Field(default=1, ge=0)
os._exit(0)
"""


CALLGRIND = ("valgrind", "--tool=callgrind")


def callgrind_total(out: Path) -> int:
    found = re.search(r"^(?:summary|totals):\s+(\d+)", out.read_text(), re.MULTILINE)
    if found is None:
        raise RuntimeError("callgrind wrote no total")
    return int(found[1])


def libraries() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "callgrind.out"
        subprocess.run(
            [*CALLGRIND, f"--callgrind-out-file={out}", sys.executable, "-c", LIBRARIES],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=daemon_env(),
            check=True,
        )
        return callgrind_total(out)


def instructions(tree: Path) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        wrapper = directory / "first_rp.py"
        wrapper.write_text(WRAPPER)
        out = directory / "callgrind.out"
        pty = PtyPair(directory / "tty")
        os.set_blocking(pty.master_fd, True)
        command = daemon_command(directory, pty.path, tree)
        proc = subprocess.Popen(
            [
                "valgrind",
                "--tool=callgrind",
                f"--callgrind-out-file={out}",
                command[0],
                str(wrapper),
                *command[3:],  # without "-m cc_daemon"
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=daemon_env(tree),
            cwd=directory,
        )
        try:
            wait_first_answer(pty.master_fd, time.monotonic(), timeout=300.0)
            proc.wait(120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            pty.close()
        return callgrind_total(out)


def main() -> int:
    if shutil.which("valgrind") is None:
        print("instructions: skipped, valgrind is not installed", flush=True)
        return 0
    if sys.argv[1:] == ["--libraries"]:
        warm_bytecode([REPO])
        print(f"  {libraries() / 1e6:8.1f} M  the libraries alone, imported as the daemon does")
        return 0
    trees = [Path(arg).resolve() for arg in sys.argv[1:]] or [REPO]
    warm_bytecode(trees)
    print("== exec -> first R-P, instructions (valgrind callgrind) ==", flush=True)
    for tree in trees:
        print(f"  {instructions(tree) / 1e6:8.1f} M  {tree}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
