"""The daemon: the service and what it composes.

- `service`: the `Daemon` (routing frames, lifecycle, shutdown);
- `casting`: a cast's execution; `line_watch`: the deadlines around the line;
- `reload`, `preflight`, `simgate`, `systemd`: SIGHUP, start-up checks, the
  simulated-winch gate, systemd's notify socket;
- `sonde`, `sonar`: the duties that read those drivers and journal what they hand up;
- `status_report`, `status_server`: the status document and its unix socket;
- `simulators`: the simulated devices the edge may hand in (never imported here).
"""
