"""The simulated autopilot behind `cc-daemon --simulate` and `simulate-autopilot`.

- `pty`: a pty pair standing in for the serial cable (unplug / replug).
- `port`: frame-level asyncio I/O over the pty master or a serial port.
- `mission`: stations, transits and the water-depth field (pure).
- `autopilot`: the firmware's behaviour as a sans-IO state machine (pure).
- `ping1d`: a simulated Blue Robotics Ping1D hearing the mission's water.
- `sonar_chain`: the autopilot's sonar module on a port, with the simulated Ping1D behind it.
- `sonar_cli`: `cc-daemon simulate-sonar`, the simulated Ping1D alone.
- `console`: the live view and the end-of-run summary.
- `options`: a run's pace and options, and the daemon's settings for it (pure).
- `session`: one run's frame loop and its narration; `logtap`: the daemon's log lines.
- `summary`: the journal's casts, the per-station rows and the verdict.
- `runner`: wires them to the daemon, in-process; `commands`: the command line.

The simulator speaks to the daemon only through the wire protocol (the codec
in `cc_daemon.core.protocol`); it never reaches into the daemon's internals except
to read its status snapshot for the summary.
"""
