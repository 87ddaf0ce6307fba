"""The cast: planning, the state machine, station memory. Pure: no I/O, no clock."""
