"""The signals the daemon answers, held from the program's first instruction.

A signal whose default action ends the process must never end the daemon by
accident: a SIGHUP from an SSH session closing during start-up, a SIGTERM from
`systemctl stop` before the event loop runs, a stray SIGALRM from a library.
The entry point (`cc_daemon.__main__`) therefore installs `SignalHold` before it
imports anything heavy (argparse, asyncio, pydantic, structlog: some 0.3 s on a
laptop, more on a Pi). From then on every signal of `HELD` is caught by one
handler, installed once and never swapped, so there is no instant at which a
default action could apply:

- until a target is attached, a signal is only counted (`pending`);
- the daemon attaches a target once its event loop runs; the signals held
  until then are handed to it at once, each once, in the order they first came
  (`deliver_to`), and later ones as they come;
- every other command (`casts`, `export`, `decode` ...) calls `release`: the
  handlers that were in place before come back and the held signals are raised
  again, so a data command behaves exactly as if nothing had been held (Ctrl-C:
  exit 130; SIGHUP: the default action);
- the daemon, done, ignores them (`ignore_from_now`) before the interpreter's exit
  would give them their default action back.

What each signal does in the daemon is `cc_daemon.daemon.signals`'s; the table
is in docs/signals.md. This module imports nothing of the project and nothing
but the standard library's `signal`; it must never do more in a handler than
count or hand over.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from types import FrameType

__all__ = [
    "HELD",
    "IGNORED",
    "LEFT_ALONE",
    "RELOAD",
    "SPARE",
    "STATUS",
    "STOP",
    "SignalHold",
    "signal_name",
]

# A clean stop: the probe home, R-F, exit 0.
STOP: tuple[int, ...] = (signal.SIGTERM, signal.SIGINT, signal.SIGQUIT)
RELOAD = signal.SIGHUP  # re-read the configuration
STATUS = signal.SIGUSR1  # one status line in the log
SPARE = signal.SIGUSR2  # logged; no action
# Every other catchable signal whose default action ends the process: logged
# and ignored. The real-time signals (SIGRTMIN..SIGRTMAX) end it by default too.
IGNORED: tuple[int, ...] = (
    signal.SIGALRM,
    signal.SIGVTALRM,
    signal.SIGPROF,
    signal.SIGIO,
    signal.SIGPWR,
    signal.SIGXCPU,
    signal.SIGXFSZ,
    signal.SIGSTKFLT,
    signal.SIGTRAP,
    signal.SIGSYS,
    *range(signal.SIGRTMIN, signal.SIGRTMAX + 1),
)
# Left to their default action on purpose: SIGABRT is systemd's watchdog signal
# (a hung loop may die: the restart recovers the station); SIGSEGV, SIGBUS,
# SIGFPE and SIGILL are faults of the program itself, which ignoring would turn
# into an endless loop on the faulting instruction; SIGKILL and SIGSTOP cannot
# be caught. SIGPIPE is already ignored by Python (a write fails with EPIPE).
LEFT_ALONE: tuple[int, ...] = (
    signal.SIGABRT,
    signal.SIGSEGV,
    signal.SIGBUS,
    signal.SIGFPE,
    signal.SIGILL,
    signal.SIGKILL,
    signal.SIGSTOP,
)
HELD: tuple[int, ...] = (*STOP, RELOAD, STATUS, SPARE, *IGNORED)

Handler = Callable[[int, FrameType | None], object] | int | signal.Handlers | None


def signal_name(signum: int) -> str:
    """`SIGTERM`, or `SIGRTMIN+3` for a real-time signal that has no name of its own."""
    if signal.SIGRTMIN < signum <= signal.SIGRTMAX:
        return f"SIGRTMIN+{signum - signal.SIGRTMIN}"
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


class SignalHold:
    """One handler for every signal of `HELD`, installed once (see the module docstring)."""

    def __init__(self) -> None:
        self._previous: dict[int, Handler] = {}
        self._pending: dict[int, int] = {}  # signal -> how many, in order of first arrival
        self._target: Callable[[int], None] | None = None
        self._released = False

    @classmethod
    def hold(cls) -> SignalHold:
        """Catch every signal of `HELD`; from a thread other than the main one (a command
        run from a test's worker thread), where Python allows no handler, hold nothing."""
        held = cls()
        try:
            for signum in HELD:
                held._previous[signum] = signal.signal(signum, held._on_signal)
        except ValueError:  # not the main thread: nothing was installed
            return cls()
        return held

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        target = self._target
        if target is None:
            self._pending[signum] = self._pending.get(signum, 0) + 1
            return
        try:
            target(signum)
        except Exception:  # a handler must never raise into whatever it interrupted
            self._pending[signum] = self._pending.get(signum, 0) + 1

    @property
    def pending(self) -> dict[int, int]:
        """The signals held and not yet handed over, with how many of each came."""
        return dict(self._pending)

    def stop_requested(self) -> bool:
        return any(signum in self._pending for signum in STOP)

    def deliver_to(self, target: Callable[[int], None] | None) -> None:
        """Hand the held signals to `target` (once each), then every later one as it
        comes; `None`: count them again (the daemon is past its event loop)."""
        self._target = target
        if target is None:
            return
        while self._pending:
            signum = next(iter(self._pending))
            del self._pending[signum]
            target(signum)

    def ignore_from_now(self) -> None:
        """Ignore every held signal from now on, unless released: the daemon's last step.
        The interpreter's exit gives every Python handler its default action back, and
        a SIGHUP (an SSH session closing) or a repeated SIGTERM in those last
        milliseconds would end a clean stop by the signal instead of with its exit status."""
        if self._released:
            return
        self._target = None
        for signum in self._previous:
            signal.signal(signum, signal.SIG_IGN)

    def release(self) -> None:
        """Give back the handlers that were in place and raise what was held (a data
        command: as if nothing had been held)."""
        pending = self.restore()
        for signum in pending:
            signal.raise_signal(signum)

    def restore(self) -> dict[int, int]:
        """Give back the handlers that were in place; return (and forget) what was held.
        The daemon's end, when its command line was called in-process: the handlers
        are left as they were found, and nothing is raised into the caller."""
        if self._released:
            return {}
        self._released = True
        self._target = None
        for signum, previous in self._previous.items():
            signal.signal(signum, previous if previous is not None else signal.SIG_DFL)
        pending, self._pending = self._pending, {}
        return pending
