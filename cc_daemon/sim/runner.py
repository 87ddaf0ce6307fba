"""`cc-daemon --simulate` and `cc-daemon simulate-autopilot`: the runs themselves.

This module wires the simulator's pieces together for one run:

- `--simulate` (`run_simulation`): a pty pair in a temporary directory, the real
  daemon (`cc_daemon.daemon.service.Daemon`) in this process on the pty's slave
  symlink, the simulated autopilot on the master, the console, and at the end a
  summary read from what the autopilot saw, the daemon's status and its journal.
- `simulate-autopilot` (`run_autopilot`): the simulated autopilot alone on a
  real serial port, against a daemon elsewhere (a Raspberry Pi over a USB cable).

It talks to the daemon only through the wire and four public doors: `run()`,
`request_shutdown()`, `snapshot()` and `record_event()` (the mission, once, as
the flight plan a ground station would hand over: `store.stations`), plus the
journal file after the run.
It never edits the daemon's state, and leaves nothing behind but the journal
and its log file: the pty pair and the temporary directory are gone when a run
returns, however it ends. The options live in `options`, the frame loop in
`session`, the verdict in `summary`, the command line in `commands`.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, TextIO, cast

from cc_daemon.sim import sondesummary
from cc_daemon.sim.autopilot import Autopilot, AutopilotConfig, Phase
from cc_daemon.sim.console import SimConsole
from cc_daemon.sim.logtap import LogTap
from cc_daemon.sim.mission import Mission, make_mission
from cc_daemon.sim.nextsteps import live_steps
from cc_daemon.sim.noise import BitFlipper
from cc_daemon.sim.options import (
    REALTIME,
    AutopilotOnlyOptions,
    SimOptions,
    autopilot_config,
    daemon_settings,
    firmware_profile,
    pace_changes,
)
from cc_daemon.sim.port import FramePort
from cc_daemon.sim.pty import PtyPair
from cc_daemon.sim.session import Run
from cc_daemon.sim.statussocket import run_socket
from cc_daemon.sim.summary import EXIT_FAILED, JournalCast, build_summary, journal_casts
from cc_daemon.store.stations import PLAN_EVENT, plan_detail

if TYPE_CHECKING:
    from cc_daemon.config import Settings
    from cc_daemon.daemon.service import Daemon

READY_TIMEOUT_S = 10.0
LINGER_S = 1.0  # after the last station, listen for stray frames this long


def _headline(options: SimOptions, mission: Mission) -> str:
    pace = options.chosen_pace
    extras = [
        f"--corrupt {options.corrupt:g}" if options.corrupt else "",
        f"--drop-link-at {options.drop_link_at:g}" if options.drop_link_at is not None else "",
        "--winch-stall" if options.winch_stall else "",
        "--winch-fail-home" if options.winch_fail_home else "",
        f"--winch-fault {options.winch_fault}" if options.winch_fault != "none" else "",
        "--resend-m" if options.resend_m else "",
        f"--firmware {options.firmware}",
    ]
    noise = " ".join(e for e in extras if e)
    head = (
        f"cc-daemon --simulate: {_stations(len(mission.stations))}, seed {mission.seed}, "
        f"{pace.name} pace, {mission.total_distance_m:.0f} m of transits"
        + (
            f" ({options.lines} lines of {options.line_length_m:g} m, {options.spacing_m:g} m"
            f" apart, at {options.boat_speed_m_s:g} m/s)"
            if options.pattern == "lines"
            else ""
        )
        + (f"  [{noise}]" if noise else "")
    )
    changes = pace_changes(options)
    if changes:
        head += (
            f"\n  {pace.name} pace: boat {options.boat_speed_m_s:g} m/s; your settings changed: "
            + ", ".join(changes)
            + f" (--pace {REALTIME.name} keeps them)"
        )
    elif pace is REALTIME:
        head += (
            f"\n  {pace.name} pace: boat {options.boat_speed_m_s:g} m/s; "
            "your winch, cast and profile settings as configured"
        )
    return head


def _stations(count: int) -> str:
    return "1 station" if count == 1 else f"{count} stations"


def _status_socket(
    options: SimOptions, db_path: Path, workdir: Path, log: TextIO
) -> tuple[Path, bool]:
    """Where the run's daemon serves its status, and whether `--db` finds it there."""
    configured = options.settings.status.path if options.settings is not None else None
    if configured is not None:
        return configured, False
    return run_socket(db_path, workdir, log)


@contextlib.contextmanager
def _signals(run: Run, enabled: bool) -> Iterator[None]:
    loop = asyncio.get_running_loop()
    installed: list[signal.Signals] = []
    if enabled:
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(signum, run.on_signal)
            except (ValueError, RuntimeError, NotImplementedError):  # not the main thread
                continue
            installed.append(signum)
    try:
        yield
    finally:
        for signum in installed:
            loop.remove_signal_handler(signum)


async def run_simulation(options: SimOptions) -> int:
    """A whole survey: the daemon in this process against the simulated autopilot."""
    from cc_daemon.daemon.service import Daemon
    from cc_daemon.ground.logsetup import configure_logging, reset_logging
    from cc_daemon.sim.devices import SIMULATORS
    from cc_daemon.store import StoreError

    mission = options.mission()
    console = SimConsole(options.out, live=options.live)
    flip_out = BitFlipper(options.corrupt, options.seed * 2 + 1) if options.corrupt else None
    flip_in = BitFlipper(options.corrupt, options.seed * 2 + 2) if options.corrupt else None
    db_path = options.db_path.absolute()
    log_path = options.log_path.absolute()
    db_path.parent.mkdir(parents=True, exist_ok=True)
    notes: list[str] = []

    with (
        tempfile.TemporaryDirectory(prefix="cc-daemon-sim-") as tmp,
        PtyPair(Path(tmp) / "ttyAUTOPILOT") as pair,
        log_path.open("a", encoding="utf-8") as log_file,
    ):
        socket, findable = _status_socket(options, db_path, Path(tmp), log_file)
        settings = daemon_settings(options, pair.path, socket)
        autopilot = Autopilot(mission, autopilot_config(options, settings))
        daemon = Daemon(settings, simulation=True, simulators=SIMULATORS)
        run = Run(
            mission,
            autopilot,
            console,
            daemon=daemon,
            pair=pair,
            flip_out=flip_out,
            flip_in=flip_in,
            drop_at=options.drop_link_at,
            drop_for=options.drop_link_for,
        )
        run.tap = LogTap(log_file, run.now)
        # Logging first: the sonar link logs as it opens, and that belongs in the
        # run's narration, not printed raw above the header.
        configure_logging("json", settings.log.level, stream=cast(TextIO, run.tap))
        sonar = None
        if options.sonar:
            from cc_daemon.sim.sonar_chain import attach_sonar

            try:
                sonar = await attach_sonar(
                    autopilot,
                    run.now,
                    port=options.sonar_port,
                    workdir=Path(tmp),
                    seed=options.seed,
                )
            except BaseException:
                reset_logging()
                raise
        status, page = live_steps(db_path, socket, findable)
        console.start(
            mission,
            _headline(options, mission)
            + f"\n  watch it from another terminal: {status}\n  or in a browser: {page}",
        )
        daemon_task = asyncio.create_task(daemon.run(), name="daemon")
        daemon_exit: int | None = None
        try:
            with _signals(run, options.handle_signals):
                daemon_exit = await _survey(run, daemon, daemon_task, settings, notes)
        finally:
            try:
                # Something went wrong in the run itself: still bring the probe
                # home if the daemon can, and only then stop it at once.
                await _stop_daemon(daemon, daemon_task, settings)
            finally:
                run.drain_log()
                await run.close()
                if sonar is not None:
                    await sonar.close()
                console.stop()
                reset_logging()
        casts: list[JournalCast] | None = None
        try:
            # This run's session only: a second simulation may share the file.
            survey = daemon.journal.session_id if daemon.journal is not None else None
            if survey is None:
                raise StoreError("the daemon never opened its journal")
            casts = journal_casts(db_path, mission, survey)
            notes.extend(sondesummary.sonde_lines(db_path, survey))
        except StoreError as exc:
            notes.append(f"could not read the journal: {exc}")
        summary = build_summary(
            run,
            casts=casts,
            daemon_exit=daemon_exit,
            db_path=db_path,
            log_path=log_path,
            notes=notes,
        )
    console.print_summary(summary)
    return summary.exit_code


async def _survey(
    run: Run, daemon: Daemon, daemon_task: asyncio.Task[int], settings: Settings, notes: list[str]
) -> int | None:
    """Sail the mission against the running daemon, then stop it; its exit status."""
    autopilot = run.autopilot
    problem = await _wait_ready(daemon, daemon_task)
    if problem is None:
        # The mission, as a ground station's flight plan would give it: the journal
        # then names and counts the stations as this run's summary does.
        check = autopilot.config.check_plan
        daemon.record_event(
            PLAN_EVENT,
            **plan_detail(
                (s.name, *s.point.lat_lon, not s.too_shallow if check else None)
                for s in run.mission.stations
            ),
        )
        await run.attach_pty()
        run.t0 = time.monotonic()
        run.wall0 = time.time()
        await run.pump(
            lambda: autopilot.phase is Phase.DONE or run.interrupts > 0 or daemon_task.done()
        )
        if not run.interrupts and not daemon_task.done():
            await run.pump(lambda: run.interrupts > 0, deadline=run.now() + LINGER_S)
    else:
        notes.append(problem)
    daemon.request_shutdown()
    gave_up = autopilot.phase is Phase.DONE and not autopilot.survey_complete
    grace = _shutdown_grace_s(settings, gave_up=gave_up)
    await run.pump(daemon_task.done, deadline=run.now() + grace)
    if not daemon_task.done():
        notes.append(
            f"the daemon did not stop within {grace:.0f} s of the request: stopped at once"
        )
        daemon.request_shutdown(immediate=True)
    try:
        code = await daemon_task
    except Exception as exc:  # a daemon bug: report it in the summary, do not hide it
        notes.append(f"the daemon failed: {type(exc).__name__}: {exc}")
        code = EXIT_FAILED
    await run.collect()  # its last frames (an R-F) may still be on the wire
    run.status = daemon.snapshot()
    autopilot.finish(run.now(), interrupted=run.interrupts > 0)
    return code


async def _stop_daemon(daemon: Daemon, task: asyncio.Task[int], settings: Settings) -> None:
    """Make sure the daemon has stopped: gracefully within the grace, else at once."""
    if task.done():
        return
    daemon.request_shutdown()
    await asyncio.wait({task}, timeout=_shutdown_grace_s(settings, gave_up=False))
    if not task.done():
        daemon.request_shutdown(immediate=True)
        await asyncio.wait({task}, timeout=10.0)
    if task.done() and not task.cancelled():
        task.exception()  # seen: the error that brought us here is the one to report


def _shutdown_grace_s(settings: Settings, *, gave_up: bool) -> float:
    """How long a graceful stop may take: a whole line's haul home, or a moment if
    the autopilot already gave up waiting for R-F (a stranded probe stays down)."""
    if gave_up:
        return 5.0
    winch = settings.winch
    speed = winch.gpio.line_speed_m_s if winch.backend == "gpio" else winch.sim.speed_m_s
    return winch.max_line_m / speed + 10.0


async def _wait_ready(daemon: Daemon, task: asyncio.Task[int]) -> str | None:
    """None once the daemon has its port open; otherwise what went wrong."""
    ready = asyncio.create_task(daemon.ready.wait(), name="daemon-ready")
    try:
        done, _ = await asyncio.wait(
            {ready, task}, timeout=READY_TIMEOUT_S, return_when="FIRST_COMPLETED"
        )
    finally:
        ready.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await ready
    if task in done:
        return "the daemon stopped before it opened its port"
    if not daemon.ready.is_set():
        return f"the daemon did not open its port within {READY_TIMEOUT_S:g} s"
    return None


# ---------------------------------------------------------------- simulate-autopilot


async def run_autopilot(options: AutopilotOnlyOptions) -> int:
    """The simulated autopilot alone on a serial port, against a daemon elsewhere."""
    mission = make_mission(options.stations, options.seed)
    console = SimConsole(options.out, live=options.live)
    profile = firmware_profile(options.firmware, None)
    if options.frame_period_s is not None:  # given on the command line: as it is
        profile["frame_period_s"] = options.frame_period_s
    config = AutopilotConfig(
        **profile,
        boat_speed_m_s=options.boat_speed_m_s,
        resend_m_during_cast=options.resend_m,
        check_plan=options.check_plan,
        finish_timeout_s=options.finish_timeout_s,
    )
    autopilot = Autopilot(mission, config)
    run = Run(mission, autopilot, console)
    port = await FramePort.over_serial(options.port, options.baudrate)
    run.attach(port)
    console.start(
        mission,
        f"cc-daemon simulate-autopilot on {options.port} at {options.baudrate} baud: "
        f"{_stations(len(mission.stations))}, seed {mission.seed}",
    )
    try:
        with _signals(run, options.handle_signals):
            run.t0 = time.monotonic()
            await run.pump(
                lambda: autopilot.phase is Phase.DONE or run.interrupts > 0 or port.hung_up
            )
            if not run.interrupts and not port.hung_up:
                await run.pump(lambda: run.interrupts > 0, deadline=run.now() + LINGER_S)
    finally:
        await run.close()
        console.stop()
    notes = ["the serial port went away"] if port.hung_up else []
    autopilot.finish(run.now(), interrupted=run.interrupts > 0)
    summary = build_summary(
        run, casts=None, daemon_exit=None, db_path=None, log_path=None, notes=notes
    )
    console.print_summary(summary)
    return summary.exit_code
