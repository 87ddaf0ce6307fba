"""The sans-IO core: bytes and events in, actions out, the time passed in.

- `protocol`: the autopilot's frames (codec and resynchronising parser);
- `cast`: the cast's plan, state machine, station memory and line-watch rules;
- `winch`: the winch's reported state (`WinchStatus`, filled in by the drivers),
  its interface, and the physics of a line on a drum;
- `status`: the daemon's state as a plain value (`DaemonStatus`);
- `errors`: the one root of the project's exceptions (the codec raises them).

It imports no asyncio, serial, socket, thread, journal or device library
(an import-linter contract in pyproject.toml keeps it so).
"""
