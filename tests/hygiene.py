"""What every test leaves behind, checked after each one: no process or thread still
running, no object whose finaliser warns (an unclosed file, a socket, a subprocess never
waited for), and the signal dispositions every test starts from.

The suite's `conftest.py` makes both checks autouse fixtures, set up before any
other fixture and so torn down after all of them: a leak is reported against
the test that made it, never against whichever test the garbage collector
happened to run in (pytest reports an unraisable `ResourceWarning` in the test
during which it was raised, and `filterwarnings = error` fails that test).
"""

from __future__ import annotations

import gc
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

# A command typed at a terminal starts with these; a suite started from a script in
# the background (`make test &`: SIGINT and SIGQUIT ignored) or under nohup (SIGHUP
# ignored) would otherwise hand SIG_IGN to every process its tests start.
TERMINAL_DISPOSITIONS: dict[int, signal.Handlers | object] = {
    signal.SIGINT: signal.default_int_handler,
    signal.SIGQUIT: signal.SIG_DFL,
    signal.SIGHUP: signal.SIG_DFL,
    signal.SIGTERM: signal.SIG_DFL,
}


def terminal_signals() -> Iterator[None]:
    """Run one test with a terminal's signal dispositions, then put back what was there.
    A Python-level handler is reset to the default action by exec, so the processes
    the test starts get SIG_DFL for each of these."""
    before = {signum: signal.getsignal(signum) for signum in TERMINAL_DISPOSITIONS}
    for signum, handler in TERMINAL_DISPOSITIONS.items():
        signal.signal(signum, handler)  # type: ignore[arg-type]
    try:
        yield
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler if handler is not None else signal.SIG_DFL)


def running_children() -> dict[int, str]:
    """This process's children that are still running (a zombie has ended: it is
    either reaped by its waiter or warned about by its `Popen` when collected)."""
    found: dict[int, str] = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            pids = (task / "children").read_text().split()
        except OSError:  # the thread ended meanwhile
            continue
        for pid in map(int, pids):
            try:
                stat = Path(f"/proc/{pid}/stat").read_text()
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
            except OSError:
                continue  # ended and reaped meanwhile
            state = stat[stat.rindex(")") + 2]
            if state not in "ZX":
                found[pid] = cmdline.replace(b"\0", b" ").decode(errors="replace").strip()
    return found


# A thread the test started is given this long to end after the test has (a writer
# draining its last rows, an executor's worker): only a hang outlasts it.
THREAD_END_S = 10.0


def threads_left(before: set[int]) -> list[str]:
    """The threads started since `before` (idents) still running after THREAD_END_S."""
    deadline = time.monotonic() + THREAD_END_S
    left = [t for t in threading.enumerate() if t.ident not in before]
    for thread in left:
        thread.join(max(0.0, deadline - time.monotonic()))
    return [thread.name for thread in left if thread.is_alive()]


def no_leaks() -> Iterator[None]:
    """Fail the test that leaves a process or a thread running (a journal's writer
    thread holds its SQLite files open: Python 3.11 never warns about those); collect
    garbage at its end so that an unclosed file, socket or subprocess warns in the
    test that leaked it."""
    before = set(running_children())
    threads = {thread.ident for thread in threading.enumerate() if thread.ident is not None}
    yield
    # Only what was allocated since the last test's end is scanned: what survived a
    # collection before is frozen (the imported libraries alone are about a million
    # objects, 0.1-1 s a full collection). A frozen object is still freed by its
    # reference count; only a cycle it joins later is never collected (memory, not
    # a missed warning of this test).
    gc.collect()
    gc.freeze()
    leaked = {pid: cmd for pid, cmd in running_children().items() if pid not in before}
    for pid in leaked:
        try:
            os.kill(pid, signal.SIGKILL)  # never into the next test
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
    assert not leaked, f"the test left processes running (killed now): {leaked}"
    still = threads_left(threads)
    assert not still, f"the test left threads running: {still}"
