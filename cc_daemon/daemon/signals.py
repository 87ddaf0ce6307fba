"""What each signal does to the running daemon (the table of docs/signals.md).

`SignalHold` (`cc_daemon.ground.signals`) catches every signal of the table from
the program's first instruction and counts it; `DaemonSignals.delivered` hands
those, then every later one, to `handle` on the event loop, so the daemon's code
never runs inside a signal handler:

- SIGTERM, SIGINT, SIGQUIT: a clean stop (no new cast; a running cast brings the
  probe home and sends R-F; exit 0). A second Ctrl-C stops the motor at once
  (exit 130); any other repetition changes nothing.
- SIGHUP: re-read the configuration (`cc_daemon.daemon.reload`).
- SIGUSR1: one line in the log saying what the daemon is doing (link, cast phase
  and depth, winch, journal).
- SIGUSR2: logged; no action.
- every other signal of `IGNORED`: logged (rate-limited like any warning) and
  ignored.

The handler installed by the hold is never swapped for the event loop's: there
is no instant at which a default action could end the daemon. The hold's own
wake-up (a socket pair given to `signal.set_wakeup_fd`) makes a signal delivered
to another thread (the journal's writer, gpiozero's) wake the loop at once.

It must never raise out of `handle` (a signal is never worth the daemon) and
never command the winch itself: stopping is the Daemon's `request_shutdown`.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import socket
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Protocol

import structlog

from cc_daemon.ground.signals import RELOAD, SPARE, STATUS, STOP, SignalHold, signal_name

if TYPE_CHECKING:
    from cc_daemon.daemon.status_report import StatusInputs

__all__ = ["DaemonSignals", "SignalTarget", "status_line", "stopped_before_ready"]

_log = structlog.get_logger("cc_daemon.signals")


class SignalTarget(Protocol):
    def request_shutdown(self, *, immediate: bool = False) -> None: ...

    def status_inputs(self) -> StatusInputs: ...


def status_line(inputs: StatusInputs) -> str:
    """The daemon in one line: link, cast phase and depth, winch, journal."""
    snap = inputs.snapshot
    link = (
        f"link {'up' if snap.link_up else 'down'} on {inputs.port} "
        f"({snap.frames_in} frames in, {snap.frames_out} out, {snap.corrupt_frames} corrupt)"
    )
    if snap.cast_id is None:
        cast = f"no cast, probe at {snap.probe_depth_m:.2f} m"
    else:
        planned = f" of {snap.planned_depth_m:.2f} m" if snap.planned_depth_m is not None else ""
        cast = f"cast {snap.cast_id} {snap.phase} at {snap.probe_depth_m:.2f} m{planned}"
    if snap.stopping:
        cast += ", stopping"
    winch = snap.winch
    if winch is None:
        winch_text = f"winch {inputs.winch_backend} not open"
    else:
        winch_text = (
            f"winch {inputs.winch_backend} {'moving' if winch.moving else 'stopped'}, "
            f"{'home' if winch.at_home else 'not home'}, "
            f"{'fault: ' + winch.fault if winch.fault else 'no fault'}"
        )
    if inputs.journal_health is None:
        journal = "journal not open"
    else:
        health = inputs.journal_health()
        journal = (
            f"journal {'writable' if health.writable else 'FAILING'}, "
            f"{health.pending_rows} rows pending, {health.rows_written} written, "
            f"{health.write_errors} write errors, {health.dropped_rows} dropped"
        )
    return "; ".join((link, cast, winch_text, journal))


class DaemonSignals:
    """The daemon's signal table; `reload` carries out a SIGHUP (None: nothing to reload)."""

    def __init__(self, daemon: SignalTarget, reload: Callable[[], None] | None = None) -> None:
        self._daemon = daemon
        self._reload = reload
        self.received: list[int] = []  # the stop signals, in order

    def handle(self, signum: int) -> None:
        """On the event loop: do what the table says for `signum`; never raises."""
        try:
            if signum in STOP:
                self._stop(signum)
            elif signum == RELOAD:
                if self._reload is None:
                    _log.info("SIGHUP ignored: nothing to reload")
                else:
                    self._reload()
            elif signum == STATUS:
                _log.info("status (SIGUSR1)", summary=status_line(self._daemon.status_inputs()))
            elif signum == SPARE:
                _log.info("SIGUSR2 received: it has no action (docs/signals.md)")
            else:
                name = signal_name(signum)
                _log.warning("signal ignored: it never stops the daemon", signal=name)
        except Exception:
            _log.error("error handling a signal", signal=signal_name(signum), exc_info=True)

    def _stop(self, signum: int) -> None:
        name = signal_name(signum)
        self.received.append(signum)
        if len(self.received) == 1:
            _log.info("signal received: bringing the probe home, then exiting", signal=name)
            self._daemon.request_shutdown()
        elif signum == signal.SIGINT and signal.SIGINT in self.received[:-1]:
            # A person pressing Ctrl-C twice means it: stop the motor, exit now.
            _log.warning("second Ctrl-C: stopping at once", signal=name)
            self._daemon.request_shutdown(immediate=True)
        else:
            # A supervisor repeating SIGTERM (or SIGQUIT) must not abandon the probe.
            _log.info("already shutting down; Ctrl-C twice stops at once", signal=name)

    @contextlib.contextmanager
    def delivered(self, held: SignalHold) -> Iterator[None]:
        """While the running loop serves: what `held` caught, then every signal, to `handle`."""
        loop = asyncio.get_running_loop()
        wake_read, wake_write = socket.socketpair()
        wake_read.setblocking(False)
        wake_write.setblocking(False)
        previous_fd = signal.set_wakeup_fd(wake_write.fileno(), warn_on_full_buffer=False)
        loop.add_reader(wake_read.fileno(), _drain, wake_read)

        def to_loop(signum: int) -> None:
            loop.call_soon_threadsafe(self.handle, signum)

        held.deliver_to(to_loop)
        try:
            yield
        finally:
            held.deliver_to(None)  # counted from here on: the loop is about to close
            loop.remove_reader(wake_read.fileno())
            signal.set_wakeup_fd(previous_fd)
            wake_read.close()
            wake_write.close()


def stopped_before_ready(held: SignalHold) -> int:
    """A stop signal came before anything was opened: say so and exit 0 (the probe
    never moved, no journal or port was touched)."""
    _log.info(
        "stop requested before the daemon was ready: exiting; nothing was opened",
        signals=[signal_name(signum) for signum in held.pending],
    )
    return 0


def _drain(wake: socket.socket) -> None:
    # The bytes only wake the loop; the hold's handler has already run (or runs
    # as soon as the main thread is back in Python) and queued `handle`.
    with contextlib.suppress(OSError):
        while wake.recv(512):
            pass
