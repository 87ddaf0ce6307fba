"""The daemon's housekeeping: what it says about itself while nothing else happens.

This module owns the duties that belong to no frame and no cast: the systemd
watchdog's ping, the log's held-back counts (`flush_rate_limited`), a log
stream lost for good (reported once, through the journal and systemd), an
open port that stays silent (`QuietPort`), and the corrupt-frame count (the
journal and the log, at most every `CORRUPT_SUMMARY_S`).

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
from cc_daemon.ground.clock import Clock
from cc_daemon.ground.logsetup import flush_rate_limited, output_loss

_log = structlog.get_logger("cc_daemon.service")

TICK_S = 1.0
CORRUPT_SUMMARY_EVERY = 10  # ticks


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
        self._output_loss_reported = False

    # ------------------------------------------------------------ told

    def port_opened(self, now: float) -> None:
        self._quiet.opened(now)

    def port_closed(self) -> None:
        self._quiet.closed()

    def heard(self) -> None:
        """A readable frame."""
        self._quiet.heard()

    def corrupt(self) -> None:
        self._quiet.corrupt()

    # ------------------------------------------------------------ the duty

    async def run(self) -> None:
        """Each second: rate-limited log summaries and the systemd watchdog; every
        10 s the corrupt-frame count (journal and log)."""
        tick = 0
        while True:
            await asyncio.sleep(TICK_S)
            flush_rate_limited()
            self._notifier.watchdog()  # every second: fine for any WatchdogSec >= 2
            self._report_output_loss()
            port = self._port()
            quiet = self._quiet.due(self._clock.monotonic(), port)
            if quiet is not None:
                _log.warning(quiet, port=port)
                self._notifier.notify(f"STATUS={quiet}")
            tick += 1
            if tick % CORRUPT_SUMMARY_EVERY:
                continue
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
