"""`cc-daemon status`: the running daemon's status document, read from its socket.

- `client`: reading one document from the socket (`cc-daemon status`, `doctor`);
- `view`: the document for a person, once or live;
- `command`: the command, its output and exit status.

The document is made by `cc_daemon.daemon.status_report` and served by
`cc_daemon.daemon.status_server`.
"""
