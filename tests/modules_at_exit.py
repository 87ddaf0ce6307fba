"""Run `python -m MODULE ARGS...` in this interpreter and, at its exit, write the
names of every module it imported (`sys.modules`), one a line, to OUT.

    python tests/modules_at_exit.py OUT -- PYTHON -m MODULE ARGS...

A test helper: a wrapper (`DaemonProcess.start(prefix=...)`) that sees what a
whole run of the daemon imported, from its first line to its exit.
"""

from __future__ import annotations

import atexit
import runpy
import sys
from pathlib import Path


def main(argv: list[str]) -> None:
    out, sep, _python, dash_m, module, *args = argv
    if sep != "--" or dash_m != "-m":
        raise SystemExit(__doc__)

    def dump() -> None:
        # Only modules really loaded: a blocked import leaves None behind.
        names = sorted(name for name, mod in sys.modules.items() if mod is not None)
        Path(out).write_text("\n".join(names) + "\n")

    atexit.register(dump)
    sys.argv = [module, *args]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main(sys.argv[1:])
