"""The daemon's read-only status: what it serves, how, and who asks.

- `report`: the status document, a JSON-able dict built from the daemon's snapshot
  (one line per section to extend it);
- `server`: the unix-socket server inside the daemon (bounded, time-limited);
- `client`: reading one document from the socket (`cc-daemon status`, `doctor`);
- `view`: the document for a person, once or live;
- `clocksync`: whether the kernel says the clock is synchronised.
"""
