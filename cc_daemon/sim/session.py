"""One simulated run's moving parts and the loop that moves frames between them.

This module owns `Run`: the autopilot, the port(s) to the daemon, injected bit
flips and cable pulls, and the narration of what happens on the console. It
talks to an in-process daemon only through its `snapshot()` and
`request_shutdown()`; it never edits the daemon's state, and never decides a
run's verdict (that is `summary`'s).
"""

from __future__ import annotations

import asyncio
import time
from bisect import bisect_left
from collections.abc import Callable
from typing import TYPE_CHECKING

from cc_daemon.core.protocol import Message
from cc_daemon.sim.autopilot import Autopilot, Phase, StationLog
from cc_daemon.sim.console import MARKS, SimConsole, ViewState
from cc_daemon.sim.logtap import LogTap
from cc_daemon.sim.mission import Mission
from cc_daemon.sim.noise import BitFlipper
from cc_daemon.sim.port import FramePort, Received
from cc_daemon.sim.pty import PtyPair

if TYPE_CHECKING:
    from cc_daemon.core.status import DaemonStatus
    from cc_daemon.daemon.service import Daemon

PROGRESS_EVERY_S = 30.0  # a transit line this often while cruising, so a long leg is not silent


class Run:
    """One run's moving parts and the loop that moves frames between them."""

    def __init__(
        self,
        mission: Mission,
        autopilot: Autopilot,
        console: SimConsole,
        *,
        daemon: Daemon | None = None,
        pair: PtyPair | None = None,
        flip_out: BitFlipper | None = None,
        flip_in: BitFlipper | None = None,
        drop_at: float | None = None,
        drop_for: float = 3.0,
    ) -> None:
        self.mission = mission
        self.autopilot = autopilot
        self.console = console
        self.daemon = daemon
        self.pair = pair
        self.flip_out = flip_out
        self.flip_in = flip_in
        self.drop_at = drop_at
        self.drop_for = drop_for
        self.tap: LogTap | None = None  # the daemon's log events, for the console
        self.port: FramePort | None = None
        self.ports: list[FramePort] = []
        self.t0 = time.monotonic()
        self.wall0 = time.time()
        self.interrupts = 0
        self.link_drops = 0
        self.unplugged_at: float | None = None
        self.frames_lost = 0  # polled while the cable was out
        self.plans: dict[int, float] = {}  # station number -> planned depth (daemon snapshot)
        self.faults: dict[int, str] = {}  # station number -> winch fault (daemon snapshot)
        self.status: DaemonStatus | None = None
        self._errors_seen = 0
        self._violations_seen = 0
        self._flips_seen = {True: 0, False: 0}  # inbound? -> flips passed to the autopilot
        self._phase: Phase | None = None  # None: the first leg is not narrated yet
        self._index = autopilot.index
        self._progress_at = 0.0  # when the last "to go" line was shown
        self._link_up = False

    # ------------------------------------------------------------ time and ports

    def now(self) -> float:
        return time.monotonic() - self.t0

    def attach(self, port: FramePort) -> None:
        self.port = port
        self.ports.append(port)
        self._errors_seen = 0

    async def attach_pty(self) -> None:
        assert self.pair is not None
        self.attach(
            await FramePort.over_fd(
                self.pair.master_fd, tx_filter=self.flip_out, rx_filter=self.flip_in
            )
        )

    # ------------------------------------------------------------ the loop

    async def pump(self, done: Callable[[], bool], *, deadline: float | None = None) -> None:
        """Move frames until `done()` (or `deadline`, seconds into the run)."""
        while not done() and (deadline is None or self.now() < deadline):
            self.drain_log()
            now = self.now()
            await self._link_schedule(now)
            self._forward_noise()
            for message in self.autopilot.poll(now):
                await self._send(now, message)
            self._observe(now)
            wait = min(max(self.autopilot.next_deadline - self.now(), 0.0), 0.1)
            port = self.port
            if port is None or port.hung_up:
                await asyncio.sleep(wait)
                continue
            received = await port.receive(wait)
            self.drain_log()  # what the daemon logged before it sent this frame comes first
            self._forward_noise()
            self._on_errors(port)  # found before this frame was handed over, or with it
            if received is not None:
                self._on_received(received)

    async def collect(self, quiet_s: float = 0.2) -> None:
        """Take the frames still on their way, sending none, until `quiet_s` without one."""
        port = self.port
        if port is None:
            return
        while (received := await port.receive(quiet_s)) is not None:
            self.drain_log()
            self._forward_noise()
            self._on_errors(port)
            self._on_received(received)
        self._on_errors(port)
        self.drain_log()

    def drain_log(self) -> None:
        """Show the daemon's queued log events."""
        if self.tap is None:
            return
        for at, event in self.tap.drain():
            self.console.event(at, LogTap.describe(event))

    def _forward_noise(self) -> None:
        """Tell the autopilot when injected noise flipped bits, each way."""
        for flipper, inbound in ((self.flip_in, True), (self.flip_out, False)):
            if flipper is None:
                continue
            times = flipper.flip_times
            for flipped_at in times[self._flips_seen[inbound] :]:
                at = self._read_time(flipped_at) if inbound else flipped_at
                self.autopilot.bits_flipped(at - self.t0, inbound=inbound)
            self._flips_seen[inbound] = len(times)

    def _read_time(self, flipped_at: float) -> float:
        """The time of the read a flip on the daemon's frames was made in, which its
        frames carry (taken a moment after the flip). A frame the flip spoilt is one of
        them or begins in their bytes (the parser reads on through a spoilt frame: a
        second corrupt frame found a read later has its window open at the first's
        time), so the flip must be no later than them to excuse them."""
        for port in self.ports:  # in the order they were attached, as their reads came
            reads = port.read_times
            i = bisect_left(reads, flipped_at)
            if i < len(reads):
                return reads[i]
        return flipped_at

    async def _send(self, now: float, message: Message) -> None:
        self.console.frame_out(now, message, self._timestamp_order())
        if self.port is None:
            self.frames_lost += 1  # the firmware writes into a dead UART
            return
        try:
            await self.port.send(message)
        except OSError as exc:
            self.console.event(now, f"write failed: {exc}")

    def _timestamp_order(self) -> str:
        """How the autopilot's timestamps are read: as the daemon settled it, or, with
        no daemon here to ask (`simulate-autopilot`), as this autopilot writes them."""
        if self.daemon is not None:
            return self.daemon.snapshot().timestamp_order
        return "little" if self.autopilot.config.ucm_2023 else "big"

    def _on_received(self, received: Received) -> None:
        at = received.time - self.t0
        self.console.frame_in(at, received.message)
        self.autopilot.on_frame(at, received.message)

    def _on_errors(self, port: FramePort) -> None:
        for error, found in zip(
            port.errors[self._errors_seen :], port.error_times[self._errors_seen :], strict=True
        ):
            at = found - self.t0
            self.console.corrupt_in(at, error)
            self.autopilot.on_corrupt(at, error)
        self._errors_seen = len(port.errors)

    async def _link_schedule(self, now: float) -> None:
        if self.pair is None or self.drop_at is None:
            return
        if self.unplugged_at is None and self.link_drops == 0 and now >= self.drop_at:
            if self.port is not None:
                self.port.detach()
                self.port = None
            self.pair.unplug()
            self.unplugged_at = now
            self.link_drops += 1
            self.autopilot.link_down(now)
            self.console.event(now, f"cable pulled for {self.drop_for:g} s")
        elif self.unplugged_at is not None and now >= self.unplugged_at + self.drop_for:
            self.pair.replug()
            await self.attach_pty()
            self.unplugged_at = None
            self.autopilot.link_up(now)
            self.console.event(now, "cable plugged back in: the daemon must reopen the port")

    # ------------------------------------------------------------ watching

    def _observe(self, now: float) -> None:
        ap = self.autopilot
        if ap.phase is not self._phase or ap.index != self._index:
            self._narrate(now)
            self._phase, self._index = ap.phase, ap.index
        elif ap.phase is Phase.CRUISING and now - self._progress_at >= PROGRESS_EVERY_S:
            self._cruise_progress(now)
        for violation in ap.violations[self._violations_seen :]:
            self.console.event(
                now,
                ("excused " if violation.excused else "VIOLATION ")
                + str(violation.kind)
                + f": {violation.detail}",
            )
        self._violations_seen = len(ap.violations)
        status = self.daemon.snapshot() if self.daemon is not None else None
        self.status = status or self.status
        station = ap.station
        if status is not None and station is not None:
            at_station = ap.phase in (Phase.REQUESTING, Phase.CASTING)
            if at_station and status.planned_depth_m is not None:
                self.plans[station.number] = status.planned_depth_m
            if at_station and status.winch_fault:
                self.faults[station.number] = status.winch_fault
            if status.link_up != self._link_up:
                self._link_up = status.link_up
                self.console.event(
                    now, "daemon: port open" if status.link_up else "daemon: port lost"
                )
        self.console.update(self._view(now, status))

    def _narrate(self, now: float) -> None:
        ap = self.autopilot
        old_log = ap.logs[self._index]
        was_at_station = self._phase in (Phase.REQUESTING, Phase.CASTING)
        if was_at_station and old_log.finished_at is not None:
            self.console.event(
                now,
                f"{old_log.station.name}: R-F, leaving; {old_log.reports} depth reports, "
                f"deepest {old_log.max_depth_m:.2f} m",
            )
        station = ap.station
        if station is None:
            if ap.phase is Phase.DONE:
                self.console.event(now, "survey over")
            return
        if ap.phase is Phase.CRUISING:
            length = self.mission.leg_length_m(ap.index)
            speed = ap.config.boat_speed_m_s
            self.console.event(
                now,
                f"under way to {station.name}: {length:.0f} m at {speed:g} m/s, "
                f"ETA {length / speed:.0f} s",
            )
            self._progress_at = now
        elif ap.phase is Phase.REQUESTING:
            self.console.event(
                now,
                f"{station.name}: on station in {station.water_depth_m:.2f} m of water; "
                "sending M until R-O",
            )
        elif ap.phase is Phase.CASTING:
            self.console.event(now, f"{station.name}: R-O, the daemon has the station")
        elif ap.phase is Phase.JOGGING:
            self.console.event(
                now, f"{station.name}: the safety pilot jogs the probe: stick down, then up"
            )

    def _cruise_progress(self, now: float) -> None:
        """On a long transit (real pace), how far there is still to go, now and then."""
        ap = self.autopilot
        station = ap.station
        if station is None:
            return
        to_go = ap.to_go_m(now)
        speed = ap.config.boat_speed_m_s
        self.console.event(
            now, f"under way to {station.name}: {to_go:.0f} m to go, ETA {to_go / speed:.0f} s"
        )
        self._progress_at = now

    def _view(self, now: float, status: DaemonStatus | None) -> ViewState:
        ap = self.autopilot
        station = ap.station
        at_station = ap.phase in (Phase.REQUESTING, Phase.CASTING)
        lat, lon = ap.position(now).lat_lon
        problems = len(ap.problems)
        return ViewState(
            elapsed_s=now,
            station_number=None if station is None else station.number,
            stations_done=sum(1 for log in ap.logs if log.finished_at is not None),
            station_count=len(ap.logs),
            autopilot_phase=str(ap.phase),
            water_depth_m=station.water_depth_m if (station and at_station) else None,
            probe_depth_m=status.probe_depth_m if status else ap.probe_depth_m,
            planned_depth_m=(
                status.planned_depth_m
                if status and status.planned_depth_m is not None
                else (self.plans.get(station.number) if station and at_station else None)
            ),
            daemon_phase=(f"jog {status.jog}" if status.jog else status.phase)
            if status
            else "remote",
            daemon_link_up=status.link_up if status else self.port is not None,
            cable_plugged=self.unplugged_at is None,
            frames_out=sum(len(p.sent) for p in self.ports),
            frames_in=sum(len(p.received) for p in self.ports),
            corrupt_in=sum(len(p.errors) for p in self.ports),
            corrupt_at_daemon=status.corrupt_frames if status else 0,
            problems=problems,
            excused=len(ap.violations) - problems,
            lat_deg=lat,
            lon_deg=lon,
            progress=[(log.station.name, self._mark(log)) for log in ap.logs],
        )

    def _mark(self, log: StationLog) -> str:
        if log.finished_at is None:
            current = self.autopilot.station is log.station
            return MARKS["current"] if current else MARKS["pending"]
        if log.problems:
            return MARKS["failed"]
        return MARKS["measured"] if log.reports else MARKS["skipped"]

    # ------------------------------------------------------------ signals

    def on_signal(self) -> None:
        self.interrupts += 1
        now = self.now()
        if self.daemon is None:
            self.console.event(now, "interrupted")
            return
        if self.interrupts == 1:
            idle = self.daemon.snapshot().phase == "idle"
            self.console.event(
                now,
                "Ctrl-C: no cast running, the daemon stops"
                if idle
                else "Ctrl-C: the daemon brings the probe home, then stops",
            )
            self.daemon.request_shutdown()
        else:
            self.console.event(now, "second Ctrl-C: the daemon stops at once")
            self.daemon.request_shutdown(immediate=True)

    async def close(self) -> None:
        for port in self.ports:
            await port.close()
        self.port = None
