"""The daemon's housekeeping: what it says about itself while nothing else happens.

This module owns the duties that belong to no frame and no cast: the systemd
watchdog's ping, the log's held-back counts (`flush_rate_limited`), a log
stream lost for good (reported once, through the journal and systemd), an
open port that stays silent (`QuietPort`), and the corrupt-frame count (the
journal and the log, at most every `CORRUPT_SUMMARY_S`).

Each has its own deadline, and the duty sleeps until the earliest, or until
something brings one nearer (`changed`): a port opened, a first corrupt frame,
a count held back or a log stream lost (the log tells `add_pending_listener`,
from whatever thread logged). With nothing due it does not wake at all; under
systemd's watchdog it pings at half of WatchdogSec.

It never touches the winch, a cast or the link's bytes: it is told about the
port and the frames (`port_opened`, `port_closed`, `heard`, `corrupt`) and
reports through the callables it is given.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import structlog

from cc_daemon.daemon.quiet_port import QuietPort
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.ground.clock import Clock, run_on_deadlines
from cc_daemon.ground.logsetup import (
    add_pending_listener,
    flush_rate_limited,
    output_loss,
    rate_limited_due_in,
    remove_pending_listener,
)

_log = structlog.get_logger("cc_daemon.service")

# The corrupt frames since the last count are counted (log and journal) this long
# after the first of them: one line for a burst, and never more than one per 10 s.
CORRUPT_SUMMARY_S = 10.0


class Housekeeping:
    def __init__(
        self,
        *,
        clock: Clock,
        notifier: SystemdNotifier,
        port: Callable[[], str],
        corrupt_frames: Callable[[], int],
        journal_event: Callable[..., None],
    ) -> None:
        self._clock = clock
        self._notifier = notifier
        self._port = port
        self._corrupt_frames = corrupt_frames
        self._journal_event: Callable[..., Any] = journal_event
        self._quiet = QuietPort()
        self._corrupt_reported = 0
        self._corrupt_due: float | None = None
        self._ping_due: float | None = None
        self._output_loss_reported = False
        # Set when something brings a deadline nearer: the sleeping duty recomputes.
        self.changed = asyncio.Event()

    # ------------------------------------------------------------ told

    def port_opened(self, now: float) -> None:
        self._quiet.opened(now)
        self.changed.set()

    def port_closed(self) -> None:
        self._quiet.closed()

    def heard(self) -> None:
        """A readable frame."""
        self._quiet.heard()

    def corrupt(self, now: float) -> None:
        self._quiet.corrupt()
        if self._corrupt_due is None:
            self._corrupt_due = now + CORRUPT_SUMMARY_S
            self.changed.set()

    # ------------------------------------------------------------ each wake-up

    def next_deadline(self, now: float) -> float | None:
        """When `tick` next has something to do; None: nothing until `changed` is set."""
        held = rate_limited_due_in()
        due = [
            deadline
            for deadline in (
                self._ping_due,
                self._quiet.next_due(),
                self._corrupt_due,
                None if held is None else now + held,
            )
            if deadline is not None
        ]
        return min(due, default=None)

    def tick(self, now: float) -> None:
        """Whatever is due at `now` (what is not is left for its own time)."""
        flush_rate_limited()
        ping = self._notifier.ping_every_s
        if ping is not None:
            if self._ping_due is None:
                self._ping_due = now + ping  # the first ping, one interval after the start
            elif now >= self._ping_due:
                self._notifier.watchdog()
                self._ping_due = now + ping
        self._report_output_loss()
        port = self._port()
        quiet = self._quiet.due(now, port)
        if quiet is not None:
            _log.warning(quiet, port=port)
            self._notifier.notify(f"STATUS={quiet}")
        if self._corrupt_due is not None and now >= self._corrupt_due:
            self._corrupt_due = None
            corrupt = self._corrupt_frames()
            if corrupt != self._corrupt_reported:
                new = corrupt - self._corrupt_reported
                self._corrupt_reported = corrupt
                _log.warning("corrupt frames received", new=new, total=corrupt)
                self._journal_event("corrupt_frames", new=new, total=corrupt)

    def _report_output_loss(self) -> None:
        """A log stream gone for good (a closed terminal): say so where it can be seen."""
        loss = output_loss()
        if loss is None or self._output_loss_reported:
            return
        self._output_loss_reported = True
        self._journal_event("log_output_lost", error=loss.error)
        self._notifier.notify(f"STATUS=log output lost ({loss.error}); events go to the journal")

    # ------------------------------------------------------------ the duty

    async def run(self) -> None:
        """Asleep until the next deadline, or until something brings one nearer."""
        loop = asyncio.get_running_loop()

        def wake() -> None:  # from any thread that logs (never raises: the log catches it)
            loop.call_soon_threadsafe(self.changed.set)

        add_pending_listener(wake)
        try:
            await run_on_deadlines(self._clock, self.changed, self.tick, self.next_deadline)
        finally:
            remove_pending_listener(wake)
