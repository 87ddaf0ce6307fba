"""Issue 22's goals: start at once, sleep when idle, stay small.

Each goal is printed with its figure and PASS/FAIL. The daemon runs as the
service does: a subprocess with the shipped configuration (config/cc-daemon.toml)
whose backends are simulated (`--winch sim`; no sonde, no sonar, as shipped),
a JSON log, on a pty pair, with its bytecode compiled as an install leaves it
(in a cache of the benchmark's, `PYCACHE`). The pty floor (a bare responder:
blocking read and write, no asyncio, no parsing) is measured in the same run.

- exec -> first R-P: the median of `BENCH_STARTS` starts (7), each asking S every
  10 ms from the moment of exec (interleaved with another tree's starts if
  `BENCH_BASELINE` names one), and the modules imported by then (`-X importtime`);
  and the same under a 10 % CPU quota (a cgroup:
  v2 `cpu.max`, else v1 `cpu.cfs_quota_us`; skipped with a message where the
  machine does not allow it);
- idle, over `BENCH_IDLE_S` (30) seconds after a 2 s settle: each thread's
  wake-ups (the kernel's voluntary context switches), CPU (the threads'
  schedstat run time, in ns) and resident memory at the end;
- R-P latency during a cast (an M starts one with a long dwell), p50 and p99
  over 1,000 S, against the floor;
- under a flood (`BENCH_GOALS_FLOOD_S`, 10 s, of P-T at the pty's full speed
  with a P-S every 4 kB, `benchmarks.flood`): peak resident memory and R-P p99;
  and, for scale, what any reader that checks the bytes ahead of a P-S must get
  through first: the bytes a pty holds (written until it refuses more) and the
  time our parser alone (in this process) takes over that many P-T.

For scale beside the start, the least any start can take with the house's
libraries: a bare interpreter, nothing of ours, that imports pydantic and
validates a one-field model (the configuration must be validated, with pydantic,
before the daemon touches the port), exec to exit; the median of as many runs,
and of 3 under the quota.

    python -m benchmarks.goals      (or: make bench)
"""

from __future__ import annotations

import contextlib
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from benchmarks.daemon import (
    BARE_RESPONDER,
    drain,
    percentile,
    read_exactly,
    rss_mb,
    station,
    wait_first_answer,
)
from benchmarks.flood import CHUNK_FRAMES, Flood, peak_rss_mb
from cc_daemon.core.protocol import Parser, ProbePositionRequest, Sender, Telemetry, encode
from cc_daemon.sim.pty import PtyPair

REPO = Path(__file__).resolve().parent.parent
SHIPPED = REPO / "config" / "cc-daemon.toml"
STARTS = int(os.environ.get("BENCH_STARTS", "7"))
IDLE_S = float(os.environ.get("BENCH_IDLE_S", "30"))
FLOOD_S = float(os.environ.get("BENCH_GOALS_FLOOD_S", "10"))
REQUESTS = 1000
# Another tree of cc-daemon (`git worktree add /tmp/old <commit>`) to start
# interleaved with this one: its start-up and import figures are printed beside.
BASELINE = Path(os.environ["BENCH_BASELINE"]) if os.environ.get("BENCH_BASELINE") else None
PYCACHE = Path(tempfile.gettempdir()) / f"cc-daemon-bench-pycache-{os.getuid()}"
QUOTA = 0.10  # a Raspberry Pi Zero 2 W is about a tenth of this machine's core


def daemon_command(directory: Path, link: Path, tree: Path = REPO) -> list[str]:
    return [
        sys.executable,
        "-m",
        "cc_daemon",
        "--config",
        str(tree / "config" / "cc-daemon.toml"),
        "--port",
        str(link),
        "--db",
        str(directory / "journal.db"),
        "--winch",
        "sim",
        "--log-format",
        "json",
    ]


def daemon_env(tree: Path = REPO) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CC_DAEMON_")}
    env.pop("RUNTIME_DIRECTORY", None)
    # The simulated winch, asked for in so many words as outside --simulate it must be.
    env.update(PYTHONPATH=str(tree), CC_DAEMON_WINCH__SIM__ALLOW_OUTSIDE_SIMULATION="true")
    # Bytecode cached, as on the Pi (pip and Debian compile it at install): without
    # it (PYTHONDONTWRITEBYTECODE, a read-only checkout) every start compiles every
    # module of the tree from source, which is no figure of the daemon's.
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = str(PYCACHE)
    return env


def warm_bytecode(trees: Sequence[Path]) -> None:
    """Compile the trees into PYCACHE and start each once (not measured), so the
    standard library's and the venv's bytecode is in PYCACHE too."""
    env = dict(os.environ, PYTHONPYCACHEPREFIX=str(PYCACHE))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    for tree in trees:
        subprocess.run(
            [sys.executable, "-m", "compileall", "-q", str(tree / "cc_daemon")], env=env, check=True
        )


def start(
    directory: Path,
    link: Path,
    preexec: Callable[[], None] | None = None,
    tree: Path = REPO,
    stderr: Any = subprocess.DEVNULL,
    python_flags: Sequence[str] = (),
) -> subprocess.Popen[bytes]:
    command = daemon_command(directory, link, tree)
    return subprocess.Popen(
        [command[0], *python_flags, *command[1:]],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=stderr,
        env=daemon_env(tree),
        cwd=directory,
        preexec_fn=preexec,  # noqa: PLW1509  (single-threaded here: writes our pid to a cgroup)
    )


def stop(proc: subprocess.Popen[bytes]) -> None:
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


# ------------------------------------------------------------------ latency


def rp_latencies(fd: int, requests: int) -> list[float]:
    """S after S: ms from the request's last byte written to its R-P read whole
    (an R-M of the cast, 8 bytes too, is skipped)."""
    frame = encode(ProbePositionRequest(72))
    out: list[float] = []
    for _ in range(requests):
        os.write(fd, frame)
        began = time.perf_counter_ns()
        while read_exactly(fd, 8)[:2] != b"RP":
            pass
        out.append((time.perf_counter_ns() - began) / 1e6)
    return out


def floor_latencies(directory: Path) -> list[float]:
    pty = PtyPair(directory / "ttyFloor")
    os.set_blocking(pty.master_fd, True)
    bare = subprocess.Popen(
        [sys.executable, "-c", BARE_RESPONDER, str(pty.path)], stdout=subprocess.PIPE
    )
    try:
        assert bare.stdout is not None
        bare.stdout.readline()
        return rp_latencies(pty.master_fd, REQUESTS)
    finally:
        bare.kill()
        bare.wait()
        pty.close()


# ------------------------------------------------------------------ start-up


def startup_s(
    directory: Path, name: str, preexec: Callable[[], None] | None = None, tree: Path = REPO
) -> tuple[float, float]:
    """Seconds from exec to the first R-P, and the CPU seconds the daemon used by then
    (less sensitive to a busy neighbour than the wall time)."""
    pty = PtyPair(directory / name)
    os.set_blocking(pty.master_fd, True)
    began = time.monotonic()
    proc = start(directory, pty.path, preexec, tree)
    try:
        took = wait_first_answer(pty.master_fd, began, timeout=60.0)
        return took, sum(ns for _, ns in threads(proc.pid).values()) / 1e9
    finally:
        stop(proc)
        pty.close()
        for stale in directory.glob("journal.db*"):
            stale.unlink()


# What the daemon cannot start without, and nothing of ours: pydantic validating
# a model, with no plugin search (as `ground.leanimports` builds the daemon's).
PYDANTIC_FLOOR = """
from pydantic import BaseModel

class One(BaseModel):
    x: int = 1

One(x=2)
"""


def library_floor_s(preexec: Callable[[], None] | None = None) -> float:
    """Seconds from exec to exit of a bare interpreter running PYDANTIC_FLOOR."""
    env = dict(daemon_env(), PYDANTIC_DISABLE_PLUGINS="__all__")
    began = time.monotonic()
    subprocess.run(
        [sys.executable, "-c", PYDANTIC_FLOOR],
        env=env,
        check=True,
        preexec_fn=preexec,  # single-threaded here: writes our pid to a cgroup
    )
    return time.monotonic() - began


def modules_at_ready(directory: Path, tree: Path = REPO) -> int:
    """How many modules the daemon imported by its first R-P (`-X importtime`)."""
    pty = PtyPair(directory / "ttyImports")
    os.set_blocking(pty.master_fd, True)
    log = directory / "importtime.txt"
    with log.open("wb") as err:
        proc = start(directory, pty.path, tree=tree, stderr=err, python_flags=("-X", "importtime"))
        try:
            wait_first_answer(pty.master_fd, time.monotonic(), timeout=60.0)
        finally:
            proc.kill()
            proc.wait()
            pty.close()
    lines = log.read_text(errors="replace").splitlines()
    return sum(1 for line in lines if line.startswith("import time:") and "[us]" not in line)


class CpuQuota:
    """A cgroup holding the processes it is given to `share` of one CPU, or why not."""

    def __init__(self, share: float) -> None:
        self.path: Path | None = None
        self.why_not = ""
        period = 100_000
        quota = int(period * share)
        v2 = Path("/sys/fs/cgroup")
        v1 = Path("/sys/fs/cgroup/cpu")
        name = f"cc-daemon-bench-{os.getpid()}"
        try:
            controllers = v2 / "cgroup.controllers"
            if controllers.exists() and "cpu" in controllers.read_text().split():
                self.path = v2 / name
                self.path.mkdir()
                (self.path / "cpu.max").write_text(f"{quota} {period}\n")
            elif (v1 / "cpu.cfs_quota_us").exists():
                self.path = v1 / name
                self.path.mkdir()
                (self.path / "cpu.cfs_period_us").write_text(f"{period}\n")
                (self.path / "cpu.cfs_quota_us").write_text(f"{quota}\n")
            else:
                self.why_not = "no cgroup cpu controller (v2 cpu.max or v1 cfs quota) here"
        except OSError as exc:
            self.why_not = f"cannot make a cgroup with a CPU quota ({exc}; it needs root)"
            self.close()

    def enter(self) -> None:
        """In the child, before exec: join the cgroup."""
        assert self.path is not None
        (self.path / "cgroup.procs").write_text(f"{os.getpid()}\n")

    def close(self) -> None:
        if self.path is not None:
            with contextlib.suppress(OSError):  # never made, or not yet empty
                self.path.rmdir()
            self.path = None


# ------------------------------------------------------------------ idle


def threads(pid: int) -> dict[int, tuple[int, int]]:
    """Each thread: (voluntary context switches, run time in ns)."""
    out: dict[int, tuple[int, int]] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            status = (task / "status").read_text()
            run_ns = int((task / "schedstat").read_text().split()[0])
        except (OSError, IndexError, ValueError):
            continue  # a thread that ended meanwhile
        switches = int(status.split("voluntary_ctxt_switches:")[1].split()[0])
        out[int(task.name)] = (switches, run_ns)
    return out


def idle(directory: Path) -> tuple[float, float, float, float]:
    """Main-thread wake-ups/s, other threads' wake-ups/s, CPU % of a core, RSS MiB."""
    pty = PtyPair(directory / "ttyIdle")
    os.set_blocking(pty.master_fd, True)
    proc = start(directory, pty.path)
    try:
        wait_first_answer(pty.master_fd, time.monotonic())
        time.sleep(2.0)
        drain(pty.master_fd)
        before, t0 = threads(proc.pid), time.monotonic()
        time.sleep(IDLE_S)
        after, elapsed = threads(proc.pid), time.monotonic() - t0
        rss = rss_mb(proc.pid)
    finally:
        stop(proc)
        pty.close()
    main_wakes = (after[proc.pid][0] - before.get(proc.pid, (0, 0))[0]) / elapsed
    other_wakes = (
        sum(s - before.get(tid, (0, 0))[0] for tid, (s, _) in after.items() if tid != proc.pid)
        / elapsed
    )
    run_ns = sum(ns - before.get(tid, (0, 0))[1] for tid, (_, ns) in after.items())
    return main_wakes, other_wakes, run_ns / 1e9 / elapsed * 100, rss


# ------------------------------------------------------------------ load


def during_a_cast(directory: Path) -> list[float]:
    pty = PtyPair(directory / "ttyCast")
    os.set_blocking(pty.master_fd, True)
    proc = start(directory, pty.path)
    try:
        wait_first_answer(pty.master_fd, time.monotonic())
        drain(pty.master_fd)
        os.write(pty.master_fd, encode(station()))  # a cast: 5 m, 10 s at the bottom
        while read_exactly(pty.master_fd, 6)[:2] != b"RO":
            pass
        return rp_latencies(pty.master_fd, REQUESTS)
    finally:
        proc.kill()  # the probe is simulated: no need to bring it home
        proc.wait()
        pty.close()


def under_a_flood(directory: Path) -> tuple[float, list[float], bool]:
    pty = PtyPair(directory / "ttyFlood")
    os.set_blocking(pty.master_fd, True)
    proc = start(directory, pty.path)
    try:
        wait_first_answer(pty.master_fd, time.monotonic())
        drain(pty.master_fd, 0.2)
        flood = Flood(pty.master_fd)
        writer = threading.Thread(target=flood.write, daemon=True)
        reader = threading.Thread(target=flood.read, daemon=True)
        reader.start()
        writer.start()
        time.sleep(FLOOD_S)
        flood.stop.set()
        writer.join(10)
        reader.join(10)
        peak = peak_rss_mb(proc.pid)
    finally:
        stop(proc)
        pty.close()
    return peak, flood.latencies_ms(), len(flood.answered) == len(flood.asked)


def flood_floor(directory: Path) -> tuple[int, float]:
    """Bytes a pty holds ahead of a reader, and ms our parser alone takes over as many
    bytes of P-T (the best of 20 rounds)."""
    pty = PtyPair(directory / "ttyHolds")
    held = 0
    try:
        with contextlib.suppress(BlockingIOError):
            while True:
                held += os.write(pty.master_fd, bytes(1024))
    finally:
        pty.close()
    fixes = b"".join(
        encode(Telemetry(n, -37260579, 404506308 + n, 702385, 8219, 100))
        for n in range(CHUNK_FRAMES)
    )
    stream = (fixes * (held // len(fixes) + 1))[:held]
    best = float("inf")
    for _ in range(20):
        parser = Parser(Sender.AUTOPILOT)
        began = time.perf_counter()
        for at in range(0, len(stream), 4096):
            parser.events_in_runs(stream[at : at + 4096])  # as the daemon reads them
        best = min(best, time.perf_counter() - began)
    return held, best * 1000


# ------------------------------------------------------------------ the report


class Verdicts:
    def __init__(self) -> None:
        self.failed: list[str] = []

    def line(self, goal: str, figure: str, passed: bool | None) -> None:
        word = "SKIP" if passed is None else "PASS" if passed else "FAIL"
        if passed is False:
            self.failed.append(goal)
        print(f"  {word}  {goal}: {figure}", flush=True)


def _ms(values: Sequence[float]) -> str:
    return f"p50 {percentile(list(values), 50):.3f} / p99 {percentile(list(values), 99):.3f} ms"


def main() -> int:
    print("== goals of issue 22: start at once, sleep when idle, stay small ==", flush=True)
    report = Verdicts()
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        floor = floor_latencies(directory)
        floor_p99 = percentile(floor, 99)
        print(f"  pty floor (bare responder), R-P over {REQUESTS} S: {_ms(floor)}", flush=True)

        warm_bytecode([REPO] if BASELINE is None else [REPO, BASELINE])
        startup_s(directory, "ttyWarm")
        if BASELINE is not None:
            startup_s(directory, "ttyWarmBase", tree=BASELINE)
        starts: list[tuple[float, float]] = []
        baseline: list[tuple[float, float]] = []
        for n in range(STARTS):  # interleaved with the baseline's, if any
            starts.append(startup_s(directory, f"ttyStart{n}"))
            if BASELINE is not None:
                baseline.append(startup_s(directory, f"ttyBase{n}", tree=BASELINE))
        walls = [wall for wall, _ in starts]
        took = statistics.median(walls)
        report.line(
            "exec -> first R-P, shipped config, backends simulated",
            f"median {took:.3f} s of {STARTS} (min {min(walls):.3f}, max {max(walls):.3f}; "
            f"CPU by then {statistics.median(cpu for _, cpu in starts):.3f} s) (<= 0.15 s)",
            took <= 0.15,
        )
        modules = modules_at_ready(directory)
        print(f"         modules imported by the first R-P: {modules}", flush=True)
        floors = [library_floor_s() for _ in range(STARTS)]
        print(
            "         the floor, nothing of ours: exec -> exit of an interpreter validating "
            f"one pydantic model, median {statistics.median(floors):.3f} s of {STARTS} "
            f"(min {min(floors):.3f})",
            flush=True,
        )
        if BASELINE is not None:
            then = statistics.median(wall for wall, _ in baseline)
            then_cpu = statistics.median(cpu for _, cpu in baseline)
            imported = modules_at_ready(directory, BASELINE)
            print(
                f"         baseline {BASELINE}, interleaved: median {then:.3f} s "
                f"(CPU {then_cpu:.3f} s), {imported} modules",
                flush=True,
            )
        quota = CpuQuota(QUOTA)
        if quota.path is None:
            report.line("the same under a 10 % CPU quota", f"skipped: {quota.why_not}", None)
        else:
            try:
                runs = [startup_s(directory, f"ttyQuota{n}", quota.enter)[0] for n in range(3)]
                floors = [library_floor_s(quota.enter) for _ in range(3)]
            finally:
                quota.close()
            took = statistics.median(runs)
            report.line(
                "the same under a 10 % CPU quota",
                f"median {took:.2f} s of 3 (<= 1.5 s)",
                took <= 1.5,
            )
            print(
                "         the floor under the quota, nothing of ours: median "
                f"{statistics.median(floors):.2f} s of 3",
                flush=True,
            )

        main_wakes, other_wakes, cpu, rss = idle(directory)
        report.line(
            "idle wake-ups, main thread",
            f"{main_wakes:.2f}/s over {IDLE_S:.0f} s (<= 1/s)",
            main_wakes <= 1.05,  # the housekeeping second, and a rounding of the window
        )
        report.line(
            "idle wake-ups, every other thread (the journal's writer)",
            f"{other_wakes:.2f}/s (none)",
            other_wakes == 0,
        )
        report.line("idle CPU", f"{cpu:.4f} % of a core (<= 0.03 %)", cpu <= 0.03)
        report.line(f"idle RSS after {IDLE_S + 2:.0f} s", f"{rss:.1f} MiB (<= 40)", rss <= 40)

        cast = during_a_cast(directory)
        p99 = percentile(cast, 99)
        report.line(
            "R-P during a cast",
            f"{_ms(cast)}; p99 floor + {p99 - floor_p99:.3f} ms (<= floor + 0.5)",
            p99 <= floor_p99 + 0.5,
        )

        peak, flooded, answered = under_a_flood(directory)
        report.line(
            f"RSS under a {FLOOD_S:.0f} s flood", f"peak {peak:.1f} MiB (<= 50)", peak <= 50
        )
        p99 = percentile(flooded, 99)
        report.line(
            "R-P under the flood",
            f"{_ms(flooded)}, every P-S answered: {answered}; p99 floor + "
            f"{p99 - floor_p99:.3f} ms (<= floor + 0.5)",
            answered and p99 <= floor_p99 + 0.5,
        )
        held, parse_ms = flood_floor(directory)
        print(
            f"         ahead of each P-S under the flood: up to the {held:,} bytes a pty "
            f"holds ({held // 25:,} P-T); our parser alone takes {parse_ms:.3f} ms over them",
            flush=True,
        )
    if report.failed:
        print(f"  goals missed: {'; '.join(report.failed)}", flush=True)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
