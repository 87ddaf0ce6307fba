"""Act as another user, for the tests that need a second uid (run as root).

    python -m tests.as_user UID GID[,GID...] cli ARGS...      cc-daemon ARGS, as that user
    python -m tests.as_user UID GID[,GID...] serve PATH TEXT  answer every connection with TEXT
    python -m tests.as_user UID GID[,GID...] hold PATH N      hold N connections to PATH

The process starts as root, imports what it will use, then drops to the user
(groups: the first GID is the primary one, the others supplementary): the
interpreter may live where that user cannot read (/root/.pyenv). `serve` and
`hold` print `ready` once bound or connected and stop when stdin closes. `cli
--times N ARGS` runs the command N times in one process and prints each exit
status and output as JSON. `cli --watch-drum` first records the simulated drum `winch --mock` would
build, and prints `drum: {json}` on stderr at the end (was one built, did its
motor run).
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import resource
import socket
import struct
import sys
import threading
from typing import Any

PRELOAD = (
    "cc_daemon.cli.app",
    "cc_daemon.cli.parser",
    "cc_daemon.cli.output",
    "cc_daemon.cli.release",
    "cc_daemon.cli.winch",
    "cc_daemon.cli.status.command",
    "cc_daemon.cli.status.client",
    "cc_daemon.cli.status.view",
    "cc_daemon.config",
    "cc_daemon.config.loading",
    "cc_daemon.config.statuspaths",
    "cc_daemon.daemon.control_server",
    "cc_daemon.drivers.winch.factory",
    "cc_daemon.drivers.winch.gpio",
    "cc_daemon.drivers.winch.devices",
    "cc_daemon.drivers.winch.motor",
    "cc_daemon.core.winch.sensors",
    "cc_daemon.ground.clock",
    "cc_daemon.ground.logsetup",
    "cc_daemon.sim.devices",
    "cc_daemon.sim.drum",
    "gpiozero",
    "gpiozero.pins.mock",
    "asyncio",
    "unicodedata",
    "encodings.idna",
)
OPTIONAL = (
    "cc_daemon.cli.daemon_socket",
    "cc_daemon.daemon.control_request",
    "rich.console",
    "rich.live",
)


def _drop(uid: int, gids: list[int]) -> None:
    os.setgroups(gids[1:])
    os.setgid(gids[0])
    os.setuid(uid)


def _watch_drum() -> dict[str, Any]:
    """Record the drum `winch --mock` builds (the real one, on gpiozero's MockFactory)."""
    import cc_daemon.sim.devices as devices
    from cc_daemon.daemon.simulators import Simulators

    seen: dict[str, Any] = {}
    build = devices.SIMULATORS.drum
    assert build is not None

    def recording(settings: Any) -> Any:
        drum = build(settings)
        seen["drum"] = drum
        return drum

    devices.SIMULATORS = Simulators(sonde=devices.SIMULATORS.sonde, drum=recording)
    return seen


def _drum_report(seen: dict[str, Any]) -> dict[str, Any]:
    drum = seen.get("drum")
    if drum is None:
        return {"built": False, "motor_ran": False}
    enable = drum.factory.pin(drum.cfg.enable_pin)
    return {"built": True, "motor_ran": any(state.state for state in enable.states)}


def cli(args: list[str]) -> int:
    seen = None
    if args[:1] == ["--watch-drum"]:
        seen, args = _watch_drum(), args[1:]
    if args[:1] == ["--times"]:
        return _repeat(int(args[1]), args[2:])
    from cc_daemon.cli.app import main

    code = main(args)
    if seen is not None:
        print(f"drum: {json.dumps(_drum_report(seen))}", file=sys.stderr)
    return code


def _repeat(times: int, args: list[str]) -> int:
    """`cc-daemon ARGS` `times` times in this process; prints [[status, output], ...]."""
    import io

    from cc_daemon.cli.app import main

    runs = []
    for _ in range(times):
        out = io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            code = main(args)
        runs.append([code, out.getvalue()])
    print(json.dumps(runs))
    return 0


def serve(path: str, text: str) -> int:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as server:
        server.bind(path)
        os.chmod(path, 0o666)
        server.listen(64)

        def answer() -> None:
            while True:
                try:
                    conn, _ = server.accept()
                except OSError:
                    return
                with conn:
                    conn.settimeout(0.2)
                    with contextlib.suppress(OSError):
                        conn.recv(4096)
                    with contextlib.suppress(OSError):
                        conn.sendall(text.encode() + b"\n")

        threading.Thread(target=answer, daemon=True).start()
        print("ready", flush=True)
        sys.stdin.read()
        server.shutdown(socket.SHUT_RDWR)
    return 0


def hold(path: str, count: int) -> int:
    """Connect `count` times (waiting in the kernel for a full backlog, 5 s at most
    each) and keep every connection open."""
    held: list[socket.socket] = []
    for _ in range(count):
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, struct.pack("ll", 5, 0))
        try:
            sock.connect(path)
        except OSError:
            sock.close()
            continue
        held.append(sock)
    print(f"ready {len(held)}", flush=True)
    sys.stdin.read()
    for sock in held:
        sock.close()
    return 0


def main(argv: list[str]) -> int:
    uid, gids, action, *rest = argv
    for name in PRELOAD:
        importlib.import_module(name)
    for name in OPTIONAL:  # not there on an older tree: the test says what it finds
        with contextlib.suppress(ImportError):
            importlib.import_module(name)
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 4096)), hard))
    _drop(int(uid), [int(g) for g in gids.split(",")])
    if action == "cli":
        return cli(rest)
    if action == "serve":
        return serve(rest[0], rest[1])
    if action == "hold":
        return hold(rest[0], int(rest[1]))
    raise SystemExit(f"unknown action {action}")


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
