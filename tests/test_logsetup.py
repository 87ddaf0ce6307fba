"""Logging: the JSON and console formats, the level filter, stdlib routing, rate limiting."""

from __future__ import annotations

import io
import json
import logging
import re
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
import structlog

from cc_daemon.ground.logsetup import (
    RateLimiter,
    add_pending_listener,
    configure_logging,
    flush_rate_limited,
    logs_at,
    rate_limited_due_in,
    remove_pending_listener,
    reset_logging,
    resolve_format,
)

ANSI = re.compile(r"\x1b\[[0-9;]*m")


class FakeClock:
    """Monotonic seconds that move only when a test says so."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Untouchable:
    """A field value that fails the test if anything renders it."""

    def __repr__(self) -> str:
        raise AssertionError("a suppressed debug event was rendered")

    __str__ = __repr__


@pytest.fixture(autouse=True)
def _restore_logging() -> Iterator[None]:
    root = logging.getLogger()
    level = root.level
    yield
    reset_logging()
    root.setLevel(level)


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


def lines(stream: io.StringIO) -> list[dict[str, Any]]:
    return [json.loads(line) for line in stream.getvalue().splitlines()]


def json_logging(clock: FakeClock, level: str = "info") -> io.StringIO:
    stream = io.StringIO()
    configure_logging("json", level, stream, rate_limit_window_s=10.0, clock=clock)
    return stream


# --- formats ----------------------------------------------------------------------------


def test_resolve_format() -> None:
    assert resolve_format("auto", Terminal()) == "console"
    assert resolve_format("auto", io.StringIO()) == "json"
    assert resolve_format("console", io.StringIO()) == "console"
    assert resolve_format("json", Terminal()) == "json"
    closed = io.StringIO()
    closed.close()
    assert resolve_format("auto", closed) == "json"
    with pytest.raises(ValueError, match="xml"):
        resolve_format("xml", io.StringIO())


def test_json_lines_have_the_journald_fields(clock: FakeClock) -> None:
    stream = json_logging(clock)
    before = datetime.now(UTC)
    log = structlog.get_logger("cc_daemon.link").bind(port="/dev/serial0")
    log.info("link up", baudrate=9600)
    log.warning("frame dropped", reason="checksum", raw="50 53 00")
    [up, dropped] = lines(stream)

    assert up["event"] == "link up"
    assert up["level"] == "info"
    assert up["logger"] == "cc_daemon.link"
    assert up["port"] == "/dev/serial0"
    assert up["baudrate"] == 9600
    assert up["timestamp"].endswith("Z")
    stamp = datetime.fromisoformat(up["timestamp"])
    assert stamp.utcoffset() == timedelta(0)
    assert before - timedelta(seconds=1) <= stamp <= datetime.now(UTC) + timedelta(seconds=1)
    assert dropped["level"] == "warning"
    assert dropped["reason"] == "checksum"


def test_json_exception_is_one_line_with_the_traceback(clock: FakeClock) -> None:
    stream = json_logging(clock)
    try:
        raise OSError(5, "Input/output error")
    except OSError:
        structlog.get_logger("cc_daemon.link").exception("port failed")
    assert len(stream.getvalue().splitlines()) == 1
    [line] = lines(stream)
    assert line["level"] == "error"
    assert "OSError: [Errno 5] Input/output error" in line["exception"]


def test_console_is_readable_and_plain_when_not_a_terminal() -> None:
    stream = io.StringIO()
    configure_logging("console", "info", stream)
    structlog.get_logger("cc_daemon.cast").info("cast started", station=4, target_m=5.0)
    output = stream.getvalue()
    assert not ANSI.search(output)
    assert "cast started" in output
    assert "info" in output
    assert "cc_daemon.cast" in output
    assert "station=4" in output
    assert "target_m=5.0" in output
    assert output.count("\n") == 1


def test_console_has_colours_on_a_terminal() -> None:
    stream = Terminal()
    configure_logging("auto", "info", stream)
    structlog.get_logger("cc_daemon.cast").warning("probe slow", depth_m=2.5)
    output = stream.getvalue()
    assert ANSI.search(output)
    assert "probe slow" in ANSI.sub("", output)
    assert "depth_m=2.5" in ANSI.sub("", output)


def test_auto_on_a_pipe_is_json() -> None:
    stream = io.StringIO()
    configure_logging("auto", "info", stream)
    structlog.get_logger("x").info("hello")
    assert lines(stream)[0]["event"] == "hello"


# --- levels and configuration -----------------------------------------------------------


def test_debug_is_suppressed_at_info_without_rendering(clock: FakeClock) -> None:
    stream = json_logging(clock, "INFO")
    log = structlog.get_logger("cc_daemon.link")
    log.debug("frame in", frame=Untouchable())
    log.info("kept")
    assert [line["event"] for line in lines(stream)] == ["kept"]


def test_debug_is_logged_at_debug(clock: FakeClock) -> None:
    stream = json_logging(clock, "debug")
    structlog.get_logger("cc_daemon.link").debug("frame in", type="S", timestamp_s=72)
    [line] = lines(stream)
    assert (line["event"], line["level"], line["type"]) == ("frame in", "debug", "S")


def test_a_caller_can_ask_before_building_costly_fields(clock: FakeClock) -> None:
    assert logs_at(logging.DEBUG)  # not configured here: structlog's own setup decides
    json_logging(clock, "info")
    assert not logs_at(logging.DEBUG) and logs_at(logging.INFO)
    json_logging(clock, "debug")  # a reload to debug
    assert logs_at(logging.DEBUG)


def test_stdlib_logging_goes_through_the_same_chain_and_level(clock: FakeClock) -> None:
    stream = json_logging(clock, "info")
    other = logging.getLogger("serial.tools")
    other.debug("not shown")
    other.info("port opened")
    other.warning("port %s busy", "/dev/ttyUSB0")
    opened, busy = lines(stream)
    assert (opened["event"], opened["level"]) == ("port opened", "info")
    assert busy["event"] == "port /dev/ttyUSB0 busy"
    assert busy["level"] == "warning"
    assert busy["logger"] == "serial.tools"


def test_stdlib_custom_levels_count_as_the_standard_one_below(clock: FakeClock) -> None:
    stream = json_logging(clock, "info")
    logging.getLogger("lib").log(25, "notice")
    logging.getLogger("lib").log(logging.DEBUG - 5, "trace")
    [line] = lines(stream)
    assert (line["event"], line["level"]) == ("notice", "info")


def test_stdlib_debug_at_debug(clock: FakeClock) -> None:
    stream = json_logging(clock, "debug")
    logging.getLogger("asyncio").debug("Using selector: %s", "EpollSelector")
    assert lines(stream)[0]["event"] == "Using selector: EpollSelector"


def test_reconfiguring_replaces_stream_level_and_format(clock: FakeClock) -> None:
    # A logger obtained before the second configuration, as a module-level one would be.
    log = structlog.get_logger("cc_daemon.link")
    first = json_logging(clock, "info")
    log.info("one")
    logging.getLogger("asyncio").warning("one")
    second = io.StringIO()
    configure_logging("console", "warning", second, clock=clock)
    log.info("two")
    log.warning("three")
    logging.getLogger("asyncio").warning("three")

    assert [line["event"] for line in lines(first)] == ["one", "one"]
    output = second.getvalue().splitlines()
    assert len(output) == 2
    assert all("three" in line and not line.startswith("{") for line in output)
    ours = [
        h for h in logging.getLogger().handlers if type(h).__module__ == "cc_daemon.ground.logsetup"
    ]
    assert len(ours) == 1


def test_bad_level_is_refused() -> None:
    with pytest.raises(ValueError, match="loud"):
        configure_logging("json", "loud", io.StringIO())


def test_reset_removes_our_handler(clock: FakeClock) -> None:
    json_logging(clock)
    reset_logging()
    assert not [
        h for h in logging.getLogger().handlers if type(h).__module__ == "cc_daemon.ground.logsetup"
    ]
    assert flush_rate_limited() == 0


# --- rate limiting ----------------------------------------------------------------------


def test_repeats_are_held_back_then_counted(clock: FakeClock) -> None:
    stream = json_logging(clock)
    log = structlog.get_logger("cc_daemon.link")
    log.error("port failed", port="/dev/serial0")  # t = 0: passes
    for _ in range(5):
        clock.now += 1.0
        log.error("port failed", port="/dev/serial0")  # t = 1..5: held back
    assert len(lines(stream)) == 1
    assert "repeated" not in lines(stream)[0]

    clock.now += 5.0  # t = 10: the window has passed
    log.error("port failed", port="/dev/serial0")
    clock.now += 1.0
    log.error("port failed", port="/dev/serial0")  # a new window: held back
    events = lines(stream)
    assert len(events) == 2
    assert events[1]["repeated"] == 5
    assert events[1]["port"] == "/dev/serial0"


def test_different_errors_are_not_limited_together(clock: FakeClock) -> None:
    stream = json_logging(clock)
    log = structlog.get_logger("cc_daemon.link")
    log.error("port failed", port="/dev/serial0")
    log.error("port failed", port="/dev/ttyUSB0")
    log.warning("port failed", port="/dev/serial0")
    structlog.get_logger("cc_daemon.other").error("port failed", port="/dev/serial0")
    log.error("port gone", port="/dev/serial0")
    # Exceptions are identical when their type and message are; the third is a repeat.
    for error in (OSError("EIO"), OSError("ENOENT"), OSError("EIO")):
        try:
            raise error
        except OSError:
            log.exception("read failed")
    assert len(lines(stream)) == 7


def test_info_and_below_are_never_limited(clock: FakeClock) -> None:
    stream = json_logging(clock, "debug")
    log = structlog.get_logger("cc_daemon.cast")
    for _ in range(3):
        log.info("depth", depth_m=1.0)
        log.debug("frame out", type="M")
    assert len(lines(stream)) == 6


def test_flush_reports_a_burst_that_stopped(clock: FakeClock) -> None:
    stream = json_logging(clock)
    log = structlog.get_logger("cc_daemon.winch")
    for _ in range(4):
        log.critical("probe not home", depth_m=3.2)
        clock.now += 0.5
    assert flush_rate_limited() == 0  # t = 2: the window is still open
    clock.now += 8.0  # t = 10
    assert flush_rate_limited() == 1
    assert flush_rate_limited() == 0  # never reported twice...
    clock.now += 10.0
    assert flush_rate_limited() == 0  # ...not even a window later
    first, summary = lines(stream)
    assert "repeated" not in first
    assert summary["event"] == "probe not home"
    assert summary["level"] == "critical"
    assert summary["logger"] == "cc_daemon.winch"
    assert summary["depth_m"] == 3.2
    assert summary["repeated"] == 3


def test_a_held_count_says_when_it_is_due_and_tells_the_listeners_once(
    clock: FakeClock,
) -> None:
    json_logging(clock)
    told: list[int] = []
    listener = lambda: told.append(1)  # noqa: E731
    add_pending_listener(listener)
    try:
        log = structlog.get_logger("cc_daemon.link")
        assert rate_limited_due_in() is None  # nothing held: nothing to wake for
        log.warning("port busy")
        assert (told, rate_limited_due_in()) == ([], None)  # logged, not held
        clock.now += 2.0
        log.warning("port busy")  # the first repeat held back: news
        log.warning("port busy")  # a second: the same count, no news
        assert told == [1]
        assert rate_limited_due_in() == pytest.approx(8.0)  # the window's end
        clock.now += 8.0
        assert rate_limited_due_in() == 0.0
        assert flush_rate_limited() == 1
        assert rate_limited_due_in() is None
    finally:
        remove_pending_listener(listener)
    log.warning("port busy")
    log.warning("port busy")
    assert told == [1]  # removed: told no more


def test_flush_everything_at_exit(clock: FakeClock) -> None:
    stream = json_logging(clock)
    log = structlog.get_logger("cc_daemon.link")
    log.error("a")
    log.error("a")
    log.warning("b")
    log.warning("b")
    log.warning("b")
    assert flush_rate_limited() == 0
    assert flush_rate_limited(everything=True) == 2
    counts = {line["event"]: line.get("repeated") for line in lines(stream)[2:]}
    assert counts == {"a": 1, "b": 2}


def test_stdlib_repeats_are_limited_too(clock: FakeClock) -> None:
    stream = json_logging(clock)
    other = logging.getLogger("asyncio")
    for _ in range(3):
        other.error("Task exception was never retrieved")
    clock.now += 10.0
    other.error("Task exception was never retrieved")
    assert [line.get("repeated") for line in lines(stream)] == [None, 2]


def test_rate_limiter_as_a_processor(clock: FakeClock) -> None:
    limiter = RateLimiter(window_s=2.0, clock=clock)

    def event(level: str = "error") -> dict[str, Any]:
        return {"event": "stall", "level": level, "logger": "w", "timestamp": str(clock.now)}

    assert limiter(None, "error", event()) == event()
    with pytest.raises(structlog.DropEvent):
        limiter(None, "error", event())
    assert limiter(None, "info", event("info")) == event("info")
    clock.now += 2.0
    assert limiter(None, "error", event())["repeated"] == 1
    with pytest.raises(ValueError, match="window_s"):
        RateLimiter(window_s=0)


def test_rate_limiter_memory_is_bounded(clock: FakeClock) -> None:
    limiter = RateLimiter(window_s=1.0, clock=clock, max_keys=8)
    for n in range(100):
        limiter(None, "error", {"event": f"error {n}", "level": "error"})
        clock.now += 1.0
    assert len(limiter._windows) <= 8
