"""The loop watchdog: a thread that switches the motor off when the event loop goes quiet.

It owns one rule: while armed, if nobody has fed it for `timeout_s`, call `trip`
(which stops the motor) once and disarm. The event loop feeds it on every winch
tick while the motor runs; a loop that is blocked (a bug, a stuck call, a
swapping Pi) stops feeding, and the motor stops anyway.

It must never do anything but call `trip`: it does not touch the loop, the
journal or the winch's state (the winch learns of the trip from `trip` itself,
through `call_soon_threadsafe`, whenever its loop runs again).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class LoopWatchdog:
    def __init__(
        self,
        timeout_s: float,
        trip: Callable[[float], None],
        *,
        name: str = "winch-watchdog",
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        if timeout_s <= 0:
            raise ValueError("timeout_s must be > 0")
        self.timeout_s = timeout_s
        # Checked twenty times per timeout: the motor stops within 5 % of it.
        self._period_s = timeout_s / 20
        self._trip = trip
        self._now = now
        self._lock = threading.Lock()
        self._armed = False
        self._fed_at = now()
        self._closing = threading.Event()
        self.trips = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def arm(self) -> None:
        with self._lock:
            self._armed = True
            self._fed_at = self._now()

    def feed(self) -> None:
        with self._lock:
            self._fed_at = self._now()

    def disarm(self) -> None:
        with self._lock:
            self._armed = False

    @property
    def armed(self) -> bool:
        with self._lock:
            return self._armed

    def close(self) -> None:
        self._closing.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=5 * self._period_s + 1.0)

    def _run(self) -> None:
        while not self._closing.wait(self._period_s):
            with self._lock:
                silent = self._now() - self._fed_at
                fire = self._armed and silent > self.timeout_s
                if fire:
                    self._armed = False
                    self.trips += 1
            if fire:
                try:
                    self._trip(silent)
                except Exception:  # the thread must outlive a failing trip: try again
                    with self._lock:
                        self._armed = True
