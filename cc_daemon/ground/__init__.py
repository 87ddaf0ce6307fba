"""Ground utilities every floor above may use; they import nothing of the project.

- `clock`: the one injected clock (monotonic and wall time);
- `clocksync`: whether the kernel says the clock is synchronised;
- `logsetup`: structlog's set-up and rate-limited log summaries;
- `waiting`: the cadence of "still waiting for ..." reports;
- `portusers`: which process holds a serial port;
- `signals`: the signals held from the entry point's first line until the daemon takes them.
"""
