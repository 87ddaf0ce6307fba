"""Drivers: they read devices and hand readings up (a callback, a return value).

- `link`: the autopilot's serial port, supervised and reopened;
- `winch`: the winch backends (the simulated line, the GPIO winch);
- `sonde`: the Modbus sonde's reader;
- `sonar`: the Ping1D's reader.

They never import the journal, the daemon or the simulator (import-linter).
"""
