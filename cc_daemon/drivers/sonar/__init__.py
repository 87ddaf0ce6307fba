"""The Blue Robotics Ping1D echosounder (manual chapter 7), over `brping`.

- `ping`: the Ping1D message table and a resynchronising byte stream (sans-IO).
- `client`: the sonar module's behaviour: start, stream, latest reading, stop (sans-IO).
- `reader`: the client over a supervised serial link (asyncio), for the daemon
  and for the simulated autopilot.

The simulated Ping1D itself lives with the simulator, in `cc_daemon.sim.ping1d`.
"""
