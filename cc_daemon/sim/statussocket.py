"""Where a simulated run's daemon serves its status: where the tools look for it.

A daemon started by hand with `--db JOURNAL` binds its status socket by the rule
of `config.statuspaths` (beside the journal, or in the user's private directory
when the journal's directory is shared), and `cc-daemon status --db JOURNAL` and
`cc-daemon web --db JOURNAL` look there. A simulation binds there too, so the
same commands find it; only when another live run already answers on that path
(two simulations writing one journal) does it serve beside its pty instead, and
then its header names that socket. A configured `status.path` is left alone.

It connects to a socket to see whether anyone answers there, and takes an
advisory lock on the run's log file (released when the run closes it) so that
two runs starting at once cannot both take the path; it never binds, creates or
removes a socket (the daemon does).
"""

from __future__ import annotations

import contextlib
import fcntl
import socket
from pathlib import Path
from typing import IO

from cc_daemon.config.statuspaths import hand_socket_path

ANSWER_WAIT_S = 1.0


def answered(path: Path) -> bool:
    """Whether a live process accepts connections on the socket at `path`."""
    with contextlib.closing(socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)) as probe:
        probe.settimeout(ANSWER_WAIT_S)
        try:
            probe.connect(str(path))
        except OSError:
            return False  # nothing there, or a dead daemon's socket (the daemon replaces it)
    return True


def claim(log: IO[str]) -> bool:
    """Claim the journal's findable socket for this run, for as long as `log` (the
    run's log file, beside the journal, shared by every run writing it) is open:
    two runs starting together must not both decide the path is free."""
    try:
        fcntl.flock(log.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False  # another run holds it
    return True


def run_socket(journal: Path, workdir: Path, log: IO[str]) -> tuple[Path, bool]:
    """The status socket of a run writing `journal` (absolute), and whether it is the
    one `--db journal` finds (False: beside the pty in `workdir`, another run being
    there already)."""
    findable = hand_socket_path(journal)
    if findable is not None and claim(log) and not answered(findable):
        return findable, True
    return workdir / "status.sock", False
