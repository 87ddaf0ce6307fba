"""The winch backends behind one small interface (`cc_daemon.core.winch.status.Winch`).

- `simulated`: the line's physics on the event loop (`winch.backend = "sim"`);
- `gpio`, `devices`, `motor`, `watchdog`: the GPIO winch on gpiozero's pins;
- `factory`: choosing and building the configured backend, and its start-up homing.
"""
