"""The daemon: the hub that routes autopilot messages and owns the lifecycle.

It answers the autopilot from the link's read callback (a reply goes out in the
loop iteration that read the request), remembers the latest fix, decides per `M`
whether to start, repeat or refuse a cast, and runs the cast's pure machine
against the winch in a task carried out by its base (`casting.CastRunner`). The
firmware's ways go to `line_watch`, the sensors are duties of their own (`sonde`,
`sonar`), and the status socket reads `status_inputs()`.

Guarantees:
- A handler's exception is logged and never stops the read loop.
- The cast does not depend on the link: with the port gone, the cast goes on
  and keeps recording; depth reports produced meanwhile are not queued.
- R-F is sent only when the winch says the probe is home (checked by the
  machine and again here, just before writing).
- Leaving `run()` in any way leaves the winch motor stopped.
"""

from __future__ import annotations

import asyncio
import gc
from collections.abc import Awaitable, Callable, Sequence
from logging import DEBUG
from typing import TYPE_CHECKING, Any

import structlog

from cc_daemon.config import Settings
from cc_daemon.config.resolution import cast_resolution, describe_resolution
from cc_daemon.core.cast.jog import Stick
from cc_daemon.core.cast.machine import (
    CastMachine,
    Outcome,
)
from cc_daemon.core.cast.plan import Phase, SkipCast, plan_cast
from cc_daemon.core.cast.stations import StationMemory
from cc_daemon.core.cast.timestamps import AutopilotTime
from cc_daemon.core.protocol import (
    Ack,
    CorruptFrame,
    Finished,
    Message,
    Parser,
    ProbeDown,
    ProbePosition,
    ProbePositionRequest,
    ProbeUp,
    Sender,
    StartMeasuring,
    Telemetry,
    TelemetryRun,
    as_dict,
)
from cc_daemon.core.status import DaemonStatus, Fix
from cc_daemon.core.winch.status import Winch, WinchStatus, refuses_casts
from cc_daemon.daemon.casting import (
    EXIT_OK,
    EXIT_PROBE_MAY_BE_DOWN,
    EXIT_ROWS_LOST,
    ActiveCast,
    CastRunner,
)
from cc_daemon.daemon.housekeeping import Housekeeping
from cc_daemon.daemon.line_watch import LineWatch, watch_line
from cc_daemon.daemon.preflight import make_journal
from cc_daemon.daemon.restart import note_interrupted
from cc_daemon.daemon.simgate import backend_name, is_simulated, simulation_warning
from cc_daemon.daemon.simulators import NO_SIMULATORS, Simulators
from cc_daemon.daemon.sonde import SondeDuty, make_sonde
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.drivers.link import SerialLink
from cc_daemon.drivers.winch.factory import hand_move, make_winch, prepare_winch
from cc_daemon.ground.clock import Clock, SystemClock
from cc_daemon.ground.logsetup import flush_rate_limited, logs_at
from cc_daemon.store import Journal
from cc_daemon.store.interrupted import InterruptedCast

if TYPE_CHECKING:
    from cc_daemon.daemon.sonar import OnboardSonar
    from cc_daemon.daemon.status_report import StatusInputs

_log = structlog.get_logger("cc_daemon.service")


class Daemon(CastRunner):
    def __init__(
        self,
        settings: Settings,
        *,
        clock: Clock | None = None,
        winch: Winch | None = None,
        journal: Journal | None = None,
        notifier: SystemdNotifier | None = None,
        simulation: bool = False,
        simulators: Simulators = NO_SIMULATORS,
    ) -> None:
        """`simulation`: run by `--simulate` (a simulated winch is expected, not announced).
        `simulators`: what stands behind a backend set to a simulated device."""
        self.settings = settings
        self._simulators = simulators
        self._clock = clock or SystemClock()
        self._winch = winch
        self._journal = journal
        self._notifier = notifier or SystemdNotifier.from_environment()
        self._simulated_note = None if simulation else simulation_warning(settings)
        if self._simulated_note:
            self._notifier.status_prefix = self._simulated_note + " | "
        self.ready = asyncio.Event()
        self._shutdown = asyncio.Event()
        self._shutting_down = False
        self._exit_code = EXIT_OK
        self._started_at = self._clock.monotonic()
        self._time = AutopilotTime(self._started_at)
        self._stations = StationMemory(settings.cast.rearm_s, settings.cast.rearm_distance_m)
        self._line = LineWatch(
            settings,
            write=self._write_again,
            move_winch=lambda depth: hand_move(self._winch, depth) if self._winch else None,
            stop_winch=self._stop_motor,
            winch_status=self._winch_status,
            journal_event=self._journal_event,
            notify=self._notifier.notify,
        )
        self._parser = Parser(
            Sender.AUTOPILOT,
            accept_g_alias=settings.serial.accept_g_alias,
        )
        serial_settings = settings.serial
        self.link = SerialLink(
            serial_settings.port,
            on_data=self._on_data,
            on_state=self._on_link_state,
            baudrate=serial_settings.baudrate,
            bytesize=serial_settings.bytesize,
            parity=serial_settings.parity,
            stopbits=serial_settings.stopbits,
            reconnect_initial_s=serial_settings.reconnect_initial_s,
            reconnect_max_s=serial_settings.reconnect_max_s,
            on_waiting=lambda text: self._notifier.notify(f"STATUS={text}"),
        )
        self.sonar: OnboardSonar | None = None
        if settings.sonar.port is not None:  # brping is loaded only where a Ping is wired
            from cc_daemon.daemon.sonar import OnboardSonar

            self.sonar = OnboardSonar(settings.sonar, self._clock, lambda: self._journal)
        self._cast: ActiveCast | None = None
        self._tasks: asyncio.TaskGroup | None = None
        self.last_fix: Fix | None = None
        self.frames_in = 0
        self.frames_out = 0
        self.casts_completed = 0
        self.casts_aborted = 0
        self.casts_skipped = 0
        self.port_losses = 0
        self._last_depth_m = 0.0
        self._sonde: SondeDuty | None = None
        self._housekeeping = Housekeeping(
            clock=self._clock,
            notifier=self._notifier,
            port=lambda: self.link.port,
            corrupt_frames=lambda: self._parser.stats.errors,
            journal_event=self._journal_event,
        )
        self._interrupted: list[InterruptedCast] = []  # stations a killed run left held

    # ------------------------------------------------------------ lifecycle

    async def run(self) -> int:
        """Serve until shut down; return the process exit status."""
        if self._simulated_note:
            _log.critical(self._simulated_note + ": running outside --simulate as configured")
        if self._winch is None:
            self._winch = make_winch(
                self.settings,
                self._clock,
                record=self._journal_event,
                mock_drum=self._simulators.drum,
            )
        if self._journal is None:
            self._journal = make_journal(self.settings)
            for cast_id in self._journal.open():
                _log.warning("cast left unfinished by a previous run", cast_id=cast_id)
        self._journal.record_event("daemon_started", port=self.settings.serial.port)
        self._interrupted = note_interrupted(self._journal)
        self._sonde = make_sonde(
            self.settings, clock=self._clock, journal=self._journal, view=self.snapshot,
            on_bottom_contact=self.bottom_contact, simulator=self._simulators.sonde,
        )  # fmt: skip
        _log.info(
            "cc-daemon started",
            port=self.settings.serial.port,
            baudrate=self.settings.serial.baudrate,
            winch=self.settings.winch.backend,
            store=str(self._journal.path),
        )
        resolution = describe_resolution(self.settings)
        if resolution is not None:  # what the casts can resolve (docs/profiles.md)
            line, short = resolution
            (_log.warning if short else _log.info)("profile resolution: " + line)
        gc.freeze()  # start-up's objects live on: a full collection skips them (performance.md)
        try:
            # A probe left down (a crash, a power cut) comes home before READY.
            left = [cast.last_depth_m for cast in self._interrupted if cast.last_depth_m]
            await prepare_winch(
                self._winch,
                lambda: self._notifier.notify("STATUS=homing the winch"),
                left_down_m=max(left, default=None),
            )
            async with asyncio.TaskGroup() as tasks:
                self._tasks = tasks
                link_task = tasks.create_task(
                    self._keep_running("serial-link", self.link.run), name="serial-link"
                )
                housekeeping = tasks.create_task(
                    self._keep_running("housekeeping", self._housekeeping.run),
                    name="housekeeping",
                )
                status = tasks.create_task(
                    self._keep_running("status", self._serve_status), name="status"
                )
                control = tasks.create_task(
                    self._keep_running("control", self._serve_control), name="control"
                )
                sonde = self._sonde and tasks.create_task(
                    self._keep_running("sonde", self._sonde.run), name="sonde"
                )
                sonar = self.sonar
                sonar_task = sonar and tasks.create_task(
                    self._keep_running("sonar", sonar.run), name="sonar"
                )
                watch = tasks.create_task(
                    self._keep_running("line-watch", self._watch_line), name="line-watch"
                )
                # Serving from here on; the port may come later (a late USB adapter).
                self._notifier.notify("READY=1", f"STATUS=opening {self.link.port}")
                await self._shutdown.wait()
                self._notifier.notify("STOPPING=1")
                await self._finish_running_cast()
                link_task.cancel()
                housekeeping.cancel()
                status.cancel()
                control.cancel()
                if sonde:
                    sonde.cancel()
                if sonar_task:
                    sonar_task.cancel()
                watch.cancel()
            self._check_home_at_exit()
        finally:
            await self._close()
        return self._exit_code

    def request_shutdown(self, *, immediate: bool = False) -> None:
        """Graceful: start no new cast, bring the probe home, send R-F, stop.

        `immediate` (a second Ctrl-C): stop the motor now and exit at once.
        """
        if immediate:
            self._stop_motor("immediate shutdown")
            cast = self._cast
            if cast is not None:
                self._exit_code = EXIT_PROBE_MAY_BE_DOWN
                _log.critical(
                    "immediate shutdown: winch stopped, the probe may be down",
                    depth_m=round(self._probe_depth(), 3),
                    cast_id=cast.cast_id,
                )
                if cast.task is not None:
                    cast.task.cancel()
        elif not self._shutting_down:
            _log.info("shutting down: no new casts", cast_running=self._cast is not None)
        self._line.stop_jog(self._clock.monotonic(), "shutdown")
        self._shutting_down = True
        self._shutdown.set()

    @property
    def shutting_down(self) -> bool:
        return self._shutting_down

    def reload(self, settings: Settings, applied: tuple[str, ...] = ()) -> None:
        """Run with `settings` from now on; only live keys may differ (`cc_daemon.daemon.reload`).

        The next cast plans with them; a running cast keeps what it started with.
        """
        self.settings = settings
        self._stations.rearm_s = settings.cast.rearm_s
        self._stations.rearm_distance_m = settings.cast.rearm_distance_m
        with self._journaling("set_telemetry_rate") as journal:
            if journal is not None:
                journal.set_telemetry_rate(settings.store.telemetry_rate_hz)
        if applied:
            self._journal_event("config_reloaded", applied=list(applied))

    def record_event(self, kind: str, **detail: Any) -> None:
        """A journal event from outside the hub (a reload refused, say); never raises."""
        self._journal_event(kind, **detail)

    async def _close(self) -> None:
        """Stop the motor, close the journal; each step guarded so one failing
        cannot skip the next (the winch first: it is the one that matters)."""
        winch = self._winch
        if winch is not None:
            try:
                await winch.close()
            except Exception:
                _log.critical("could not close the winch backend", exc_info=True)
        cast = self._cast
        with self._journaling("close") as journal:
            if journal is not None:
                if cast is not None:  # stranded or cut short: the record says so
                    journal.end_cast(
                        cast.cast_id,
                        outcome=str(Outcome.UNFINISHED),
                        reached_depth_m=cast.machine.reached_depth_m,
                        reason=f"daemon stopped with the probe at {self._probe_depth():.2f} m",
                    )
                journal.record_event("daemon_stopped", exit_code=self._exit_code)
                journal.close()
                lost = journal.health().dropped_rows
                if lost:
                    _log.error("the journal lost rows during this run", dropped_rows=lost)
                    if self._exit_code == EXIT_OK:
                        self._exit_code = EXIT_ROWS_LOST
        _log.info("cc-daemon stopped", exit_code=self._exit_code)
        try:
            flush_rate_limited(everything=True)
        except Exception:
            _log.error("could not flush rate-limited log summaries", exc_info=True)
        self._notifier.close()

    async def _keep_running(self, name: str, duty: Callable[[], Awaitable[None]]) -> None:
        """Run a background duty for the daemon's lifetime. A crash is logged and
        the duty restarted: an exception escaping into the task group would cancel
        the running cast beside it and leave the probe down."""
        while True:
            try:
                await duty()
                _log.error("background task ended; restarting it", task=name)
            except Exception:
                _log.critical("background task crashed; restarting it", task=name, exc_info=True)
            await asyncio.sleep(1.0)

    async def _serve_status(self) -> None:
        from cc_daemon.daemon.status_server import serve_status

        def document() -> dict[str, Any]:  # the report's module: at the first client
            from cc_daemon.daemon.status_report import status_document

            return status_document(self.status_inputs())

        await serve_status(self.settings.status, document, journal=self.settings.store.path)

    def status_inputs(self) -> StatusInputs:
        """What the status document is made of, as plain values taken now."""
        from cc_daemon.daemon.status_report import StatusInputs

        now = self._clock.monotonic()
        journal = self._journal
        return StatusInputs(
            snapshot=self.snapshot(),
            port=self.link.port,
            baudrate=self.settings.serial.baudrate,
            # As the journal records it: "gpio-mock" is the GPIO winch's code on mock pins.
            winch_backend=backend_name(self.settings),
            simulated=is_simulated(self.settings),
            journal_health=journal.health if journal is not None else None,
            monotonic=now,
            wall=self._clock.wall(),
            uptime_s=now - self._started_at,
        )

    async def _watch_line(self) -> None:
        await watch_line(self._line, self._clock, lambda: self._cast is not None)

    def snapshot(self) -> DaemonStatus:
        cast = self._cast
        return DaemonStatus(
            link_up=self.link.up,
            phase=str(cast.machine.phase) if cast else "idle",
            probe_depth_m=self._probe_depth(),
            planned_depth_m=cast.machine.plan.depth_m if cast else None,
            cast_id=cast.cast_id if cast else None,
            frames_in=self.frames_in,
            frames_out=self.frames_out,
            corrupt_frames=self._parser.stats.errors,
            casts_completed=self.casts_completed,
            casts_aborted=self.casts_aborted,
            casts_skipped=self.casts_skipped,
            winch_fault=cast.machine.winch_fault if cast else None,
            fault_reports=cast.fault_reports if cast else 0,
            port_losses=self.port_losses,
            last_fix=self.last_fix,
            winch=self._winch_status() if self._winch is not None else None,
            stopping=self._shutting_down,
            jog=str(self._line.jog.stick) if self._line.jog.stick else None,
            lost_start=self._line.lost_start_text(),
            port_open_attempts=self.link.waiting.attempts,
            timestamp_order=self._line.order.order,
            timestamp_order_settled=self._line.order.decided,
        )

    @property
    def journal(self) -> Journal | None:
        return self._journal

    # ------------------------------------------------------------ link side

    def _on_link_state(self, up: bool, reason: str) -> None:
        self._line.link_changed(up, self._clock.monotonic())
        if up:
            self._housekeeping.port_opened(self._clock.monotonic())
            kind = "port_regained" if self.port_losses else "port_opened"
            self._journal_event(kind, port=self.link.port)
            self._release_interrupted()  # a station the previous run left the boat at
            self.ready.set()
            self._notifier.notify(f"STATUS=answering on {self.link.port}")
        else:
            self._housekeeping.port_closed()
            self.port_losses += 1
            self._journal_event("port_lost", port=self.link.port, reason=reason)
            self._notifier.notify(f"STATUS=serial port lost ({reason}); reopening")

    def _on_data(self, data: bytes) -> None:
        # Bytes no frame could hold (an M whose sync byte flipped) are evidence of a
        # lost M as a corrupt frame is (line_watch).
        unframed = -self._parser.stats.bytes_unframed
        # In stream order, errors included; a run of P-T back to back comes as one.
        for message in self._parser.events_in_runs(data):
            if isinstance(message, TelemetryRun):
                self._fixes(message)
            elif isinstance(message, Telemetry):
                self._fixes((message,))
            elif isinstance(message, CorruptFrame):
                now = self._clock.monotonic()
                self._line.corrupt(now)
                self._housekeeping.corrupt(now)
            else:
                self._housekeeping.heard()
                self.frames_in += 1
                try:
                    self._handle(message)
                except Exception:
                    _log.exception("error handling frame", frame=message.frame)
        if unframed + self._parser.stats.bytes_unframed > 0:
            self._line.corrupt(self._clock.monotonic())

    def _fixes(self, fixes: Sequence[Telemetry]) -> None:
        """`P-T` frames back to back in one read (a run, or one alone): one instant, so
        heard as one (a flood's path), the middle of a run never decoded. Each counts
        and is heard as if alone (`LineWatch.heard_fixes`); the last is the fix, and the
        journal keeps no other (`record_fixes`: they share an interval)."""
        self._housekeeping.heard()
        self.frames_in += len(fixes)
        last = fixes[-1]
        try:
            now = self._clock.monotonic()
            if logs_at(DEBUG):  # the fields of a frame cost more than the question
                for message in fixes:
                    _log.debug("frame in", **as_dict(message))
            self._time.observe(self._line.heard_fixes(fixes, now), now)
            self.last_fix = Fix(last, now, self._clock.wall())
            with self._journaling("record_fix") as journal:
                if journal is not None:
                    order = self._line.order
                    journal.record_fixes(fixes, decode=order.decode, ap_time_order=order.order)
        except Exception:
            _log.exception("error handling frame", frame=last.frame)

    # ------------------------------------------------------------ messages

    def _handle(self, message: Message) -> None:
        now = self._clock.monotonic()
        if logs_at(DEBUG):
            _log.debug("frame in", **as_dict(message))
        self._time.observe(self._line.heard(message, now), now)
        if isinstance(message, ProbePositionRequest):
            self._send(ProbePosition(self._time.at(now), self._depth_mm(self._probe_depth())))
        elif isinstance(message, StartMeasuring):
            self._remember_fix(message, now)
            self._line.stop_jog(now, "start-measuring")  # then as ever: home first
            self._on_start_measuring(message, now)
        elif isinstance(message, ProbeUp | ProbeDown):
            self._on_stick(Stick.UP if isinstance(message, ProbeUp) else Stick.DOWN, now)
        else:  # the parser listens to autopilot frames only (`_on_data` takes the T's)
            _log.warning("unexpected frame from the autopilot side", frame=message.frame)

    def _remember_fix(self, message: Telemetry | StartMeasuring, now: float) -> None:
        self.last_fix = Fix(message, now, self._clock.wall())
        with self._journaling("record_fix") as journal:
            if journal is not None:
                order = self._line.order
                journal.record_fix(
                    message,
                    ap_time_s=order.decode(message.timestamp_s),
                    ap_time_order=order.order,
                )

    def _on_stick(self, stick: Stick, now: float) -> None:
        """`P-U` / `P-D`: no reply ever. In a cast, U means "probe up now"."""
        cast = self._cast
        if cast is None:
            self._line.stick(stick, now)
        elif cast.machine.phase is Phase.STRANDED and stick is Stick.UP:
            # The safety pilot hauls a stranded probe in: a jog (dead-man's handle);
            # the stranded cast ends, with R-F, only once the winch verifies home.
            self._line.stick(stick, now)
        elif stick is Stick.UP:
            self._execute(cast, cast.machine.abort(now, "safety pilot: probe up (RC stick)"))
        else:
            _log.warning("probe-down stick ignored: a cast is running", cast_id=cast.cast_id)

    def _on_start_measuring(self, station: StartMeasuring, now: float) -> None:
        if self._cast is not None:
            self._send(Ack(self._time.at(now)))  # the same station, still running
            return
        if self._shutting_down:
            _log.warning("start-measuring ignored: shutting down", timestamp_s=station.timestamp_s)
            return
        self._send(Ack(self._time.at(now)))
        status = self._winch_status()
        if refuses_casts(status):  # never a cast on a winch that cannot vouch for home
            self._refuse_cast(station, status, now)
            return
        if not status.at_home:
            # Down with no cast (a restart mid-cast, a hand-lowered probe): bring
            # it home first, reporting as a cast does; this station is not measured.
            reason = f"the probe was {status.depth_m:.2f} m down with no cast running"
            _log.error("start-measuring: recovering the probe first", reason=reason)
            machine = CastMachine.recovery(
                started_at=now,
                report_period_s=self.settings.cast.report_period_s,
                home_timeout_s=self.settings.cast.max_duration_s,
                reason=reason,
            )
            self._start_cast(station, machine, now)
            return
        done = self._stations.recently_done(station, now)
        if done is not None:
            _log.info(
                "station repeated within the re-arm window: repeating R-F, no new cast",
                cast_id=done.cast_id,
                since_s=round(now - done.finished_at, 1),
                rearm_s=self.settings.cast.rearm_s,
            )
            self._send(Finished(self._time.at(now), 0))  # at home: checked above
            return
        bottom = station
        if self.sonar is not None:  # the freshest confident bottom of the two sonars
            bottom = self.sonar.station_for_plan(
                station, now, self.settings.cast.min_sonar_confidence
            )
        plan = plan_cast(
            bottom,
            self.settings.cast,
            self.settings.winch.max_line_m,
            cast_resolution(self.settings),
        )
        if isinstance(plan, SkipCast):
            self._skip_cast(station, plan, now, status)
        else:
            machine = CastMachine(
                plan,
                started_at=now,
                report_period_s=self.settings.cast.report_period_s,
                max_duration_s=self.settings.cast.max_duration_s,
            )
            self._start_cast(station, machine, now)

    def _skip_cast(
        self, station: StartMeasuring, skip: SkipCast, now: float, status: WinchStatus
    ) -> None:
        _log.warning("cast skipped: station too shallow", reason=skip.reason)
        cast_id = self._journal_start(station, skip.planned_depth_m, {"skipped": skip.reason})
        with self._journaling("end_cast") as journal:
            if journal is not None and cast_id is not None:
                journal.end_cast(
                    cast_id,
                    outcome=str(Outcome.SKIPPED_SHALLOW),
                    reached_depth_m=0.0,
                    reason=skip.reason,
                )
        self.casts_skipped += 1
        self._stations.finished(station, now, cast_id)
        self._send(Finished(self._time.at(now), 0))  # the probe never left home
