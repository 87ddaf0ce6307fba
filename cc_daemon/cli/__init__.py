"""The command faces: `app` (the daemon and the dispatch of every command), `data`
(casts, export, plot, snapshot), `sonde`, `winch`, `decode`, `live_decode`,
`status` and `doctor`. `cc_daemon.__main__` only calls `app.main`."""
