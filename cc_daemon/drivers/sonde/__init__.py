"""The multiparameter sonde over Modbus RTU (pymodbus).

- `registers`: the register map's arithmetic (sans-IO);
- `reader`: one read of the configured parameters, with its status;
- `depthcheck`: the sonde's own depth against the line out (bottom contact).

The duty that reads it every period and journals each reading is the daemon's
(`cc_daemon.daemon.sonde`); the simulated sonde lives with the simulator.
"""
