"""Where the daemon's log lines go and what they look like.

This module owns the structlog configuration: the processor chain, the two renderers
(a readable console one, colours only on a terminal; and JSON lines for journald),
the level filter, the routing of the standard library's `logging` (pyserial, asyncio)
into the same chain, and the rate limiting of repeated warnings and errors.

It must never decide *what* is logged (callers do), write anywhere but the stream it
is given, or drop an event without counting it: repeats are held back, counted and
reported with ``repeated=N`` (by the next identical event after the window, or by
`flush_rate_limited`), never silenced. Whoever flushes need not poll: it asks when
the next count is due (`rate_limited_due_in`) and is called, from whatever thread
logged, when there is something new to flush or report (`add_pending_listener`:
a count held back where none was, a stream lost).

Nor may logging ever raise into its caller: a stream that fails for good (the
terminal of a closed SSH session: EIO; a pipe whose reader left: EPIPE; a closed
file) is pointed at /dev/null, and the lines lost from then on are counted in
`output_loss()`, which the daemon reports through the journal and systemd instead.

Callers log with ``structlog.get_logger(__name__)``; the name becomes the "logger"
field.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any, Literal, TextIO

import structlog
from structlog.typing import EventDict, Processor, WrappedLogger

__all__ = [
    "LEVELS",
    "OutputLoss",
    "RateLimiter",
    "add_pending_listener",
    "configure_logging",
    "flush_rate_limited",
    "logs_at",
    "output_loss",
    "rate_limited_due_in",
    "remove_pending_listener",
    "reset_logging",
    "resolve_format",
]

LEVELS: dict[str, int] = {
    "debug": logging.DEBUG,
    "info": logging.INFO,
    "warning": logging.WARNING,
    "error": logging.ERROR,
    "critical": logging.CRITICAL,
}
# structlog method names that are not level names.
_METHOD_LEVELS = {**LEVELS, "warn": logging.WARNING, "exception": logging.ERROR}
_DEFAULT_NAME = "cc_daemon"
# Fields that differ between otherwise identical events, so not part of "identical".
_VOLATILE = frozenset({"timestamp", "exc_info", "exception", "stack_info", "repeated"})
# Marks a summary emitted by flush_rate_limited, which the limiter must let through.
_SUMMARY = "_rate_limit_summary"


def resolve_format(fmt: str, stream: TextIO) -> Literal["console", "json"]:
    """`"auto"` becomes console on a terminal and JSON lines otherwise (journald, files)."""
    if fmt == "auto":
        return "console" if _isatty(stream) else "json"
    if fmt in ("console", "json"):
        return "console" if fmt == "console" else "json"
    raise ValueError(f"log format must be 'console', 'json' or 'auto', not {fmt!r}")


def _isatty(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # a closed or unusual stream is not a terminal
        return False


# --- rate limiting ----------------------------------------------------------------------


@dataclass(slots=True)
class _Window:
    started: float
    suppressed: int = 0
    # The first suppressed event, kept to report the repeats if no later one comes.
    held: dict[str, Any] = field(default_factory=dict)


class RateLimiter:
    """A structlog processor that lets one of a burst of identical warnings through.

    Events at `min_level` or above are identical when logger, level, event and the
    other fields (not the timestamp or the traceback's text, but the exception's type
    and message) are equal. The first passes; repeats within `window_s` of it are
    dropped and counted; the first one after the window passes with
    ``repeated=<count dropped>`` and starts a new window. Counts that no later event
    reports are reported by `pending` (see `flush_rate_limited`). `clock` returns
    monotonic seconds; inject a fake one in tests.
    """

    def __init__(
        self,
        window_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
        min_level: int = logging.WARNING,
        max_keys: int = 1024,
    ) -> None:
        if window_s <= 0:
            raise ValueError(f"window_s must be > 0, not {window_s!r}")
        self.window_s = window_s
        self.min_level = min_level
        self._clock = clock
        self._max_keys = max_keys
        self._windows: dict[Hashable, _Window] = {}
        # gpiozero and pyserial threads log too.
        self._lock = threading.Lock()
        # Called, outside the lock, when a window holds back its first repeat: a
        # count is now due at the window's end (`due_in`).
        self.on_hold: Callable[[], None] | None = None

    def __call__(self, logger: WrappedLogger, method_name: str, event_dict: EventDict) -> EventDict:
        if event_dict.pop(_SUMMARY, False):
            return event_dict
        level = _METHOD_LEVELS.get(str(event_dict.get("level", method_name)), logging.NOTSET)
        if level < self.min_level:
            return event_dict
        key = _identity(event_dict)
        with self._lock:
            now = self._clock()
            window = self._windows.get(key)
            if window is None:
                self._forget_expired(now)
                self._windows[key] = _Window(now)
                return event_dict
            repeated = window.suppressed
            dropped = now - window.started < self.window_s
            if dropped:
                if repeated == 0:
                    window.held = {k: v for k, v in event_dict.items() if k not in _VOLATILE}
                window.suppressed += 1
            else:
                self._windows[key] = _Window(now)
        if dropped:
            if repeated == 0 and self.on_hold is not None:
                self.on_hold()  # the first held back: a count is due at the window's end
            raise structlog.DropEvent
        if repeated:
            event_dict["repeated"] = repeated
        return event_dict

    def pending(self, *, everything: bool = False) -> list[dict[str, Any]]:
        """Summaries of repeats whose window has passed (all of them if `everything`).

        Each is the held event with ``repeated=N``; its counter restarts, so repeats
        are never reported twice.
        """
        summaries: list[dict[str, Any]] = []
        with self._lock:
            now = self._clock()
            for window in self._windows.values():
                expired = now - window.started >= self.window_s
                if window.suppressed and (expired or everything):
                    summaries.append({**window.held, "repeated": window.suppressed})
                    window.started, window.suppressed, window.held = now, 0, {}
            self._forget_expired(now)
        return summaries

    def due_in(self) -> float | None:
        """Seconds until the next count held back is due (0: now; None: none held)."""
        with self._lock:
            now = self._clock()
            due = [w.started + self.window_s - now for w in self._windows.values() if w.suppressed]
        return max(0.0, min(due)) if due else None

    def _forget_expired(self, now: float) -> None:
        # Bounded memory: a window with nothing held back that has passed carries no
        # information. Only checked when the table is large, to keep the common path cheap.
        if len(self._windows) < self._max_keys:
            return
        for key in [
            k
            for k, w in self._windows.items()
            if not w.suppressed and now - w.started >= self.window_s
        ]:
            del self._windows[key]


def _identity(event_dict: EventDict) -> Hashable:
    parts = [(k, repr(v)) for k, v in event_dict.items() if k not in _VOLATILE]
    exc = event_dict.get("exc_info")
    if exc is True:
        exc = sys.exc_info()[1]
    elif isinstance(exc, tuple):
        exc = exc[1]
    if isinstance(exc, BaseException):
        parts.append(("exc_info", f"{type(exc).__qualname__}: {exc}"))
    return tuple(sorted(parts))


# --- configuration ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class OutputLoss:
    """The log stream failed: why, and how many lines have been lost since."""

    error: str
    lines: int


@dataclass(slots=True)
class _Loss:
    stream: TextIO | None = None
    error: str = ""
    lines: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)


_loss = _Loss()


def output_loss() -> OutputLoss | None:
    """Whether the log stream failed (and was replaced by /dev/null), and what was lost."""
    with _loss.lock:
        if _loss.stream is None:
            return None
        return OutputLoss(_loss.error, _loss.lines)


def _stream_failed(stream: TextIO, exc: BaseException) -> None:
    """Point the failed stream at /dev/null so nothing writing to it, not even the
    interpreter's last flush at exit, fails again; count the line."""
    first = False
    with _loss.lock:
        if _loss.stream is None:
            first = True
            _loss.stream, _loss.error = stream, f"{type(exc).__name__}: {exc}"
            try:
                devnull = os.open(os.devnull, os.O_WRONLY)
                try:
                    os.dup2(devnull, stream.fileno())
                finally:
                    os.close(devnull)
            except (OSError, ValueError, AttributeError):
                pass  # a stream with no file descriptor: we simply stop writing to it
        _loss.lines += 1
    if first:
        _tell_listeners()  # the loss is news for whoever reports it


# Told (from whatever thread logged) when there is news to flush or report: a count
# held back where none was, a log stream lost. Each must be cheap and thread-safe.
_listeners: list[Callable[[], None]] = []


def add_pending_listener(listener: Callable[[], None]) -> None:
    _listeners.append(listener)


def remove_pending_listener(listener: Callable[[], None]) -> None:
    with contextlib.suppress(ValueError):
        _listeners.remove(listener)


def _tell_listeners() -> None:
    for listener in tuple(_listeners):
        with contextlib.suppress(Exception):  # logging must never raise into its caller
            listener()


class _NamedWriteLogger(structlog.WriteLogger):
    """A WriteLogger that knows the name it was asked for, for the "logger" field,
    and never raises (see the module docstring)."""

    def __init__(self, file: TextIO, name: str) -> None:
        super().__init__(file)
        self.name = name

    def msg(self, message: str) -> None:
        if _loss.stream is self._file:
            with _loss.lock:
                _loss.lines += 1
            return
        try:
            super().msg(message)
        except (OSError, ValueError) as exc:  # ValueError: writing to a closed file
            _stream_failed(self._file, exc)

    log = debug = info = warn = warning = msg
    fatal = failure = err = error = critical = exception = msg


def _add_logger_name(logger: WrappedLogger, method_name: str, event_dict: EventDict) -> EventDict:
    event_dict.setdefault("logger", getattr(logger, "name", _DEFAULT_NAME))
    return event_dict


class _StdlibToStructlog(logging.Handler):
    """Feeds `logging` records (pyserial, asyncio...) into the structlog chain.

    One chain for both means one format, one level and one rate limiter. A record
    logged with ``extra={"fields": {...}}`` (as our own library code does, e.g. the
    parser) keeps those fields as structured fields.
    """

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
            extra = getattr(record, "fields", None)
            fields: dict[str, Any] = dict(extra) if isinstance(extra, dict) else {}
            if record.exc_info:
                fields["exc_info"] = record.exc_info
            # structlog knows only the five standard levels; a custom one (asyncio's
            # none, but a library may add e.g. 25) counts as the standard one below it.
            levelno = max((n for n in LEVELS.values() if n <= record.levelno), default=0)
            levelno = levelno or logging.DEBUG
            structlog.get_logger(record.name).log(levelno, message, **fields)
        except Exception:  # a logging failure must not take the caller down
            self.handleError(record)


@dataclass(slots=True)
class _Installed:
    """What the last configure_logging put in place, so the next one can replace it."""

    limiter: RateLimiter | None = None
    handler: logging.Handler | None = None
    levelno: int | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)


_installed = _Installed()


def configure_logging(
    fmt: str,
    level: str,
    stream: TextIO = sys.stderr,
    *,
    rate_limit_window_s: float = 10.0,
    clock: Callable[[], float] = time.monotonic,
) -> None:
    """Configure structlog and `logging` to write `fmt` lines at `level` and above.

    `fmt` is "console", "json" or "auto" (see `resolve_format`); `level` a name from
    `LEVELS`, any case. Calling it again replaces the previous configuration.
    """
    levelno = LEVELS.get(level.lower())
    if levelno is None:
        raise ValueError(f"log level must be one of {', '.join(LEVELS)}, not {level!r}")
    resolved = resolve_format(fmt, stream)
    limiter = RateLimiter(rate_limit_window_s, clock)

    processors: list[Processor] = [
        structlog.contextvars.merge_contextvars,
        structlog.processors.add_log_level,
        _add_logger_name,
        # Before the timestamp and rendering, so a dropped repeat costs little.
        limiter,
        structlog.processors.TimeStamper(fmt="iso", utc=True, key="timestamp"),
    ]
    if resolved == "json":
        processors += [
            structlog.processors.format_exc_info,
            structlog.processors.JSONRenderer(),
        ]
    else:
        # ConsoleRenderer formats exceptions itself (and warns if format_exc_info ran).
        colors = _isatty(stream)
        processors.append(
            structlog.dev.ConsoleRenderer(
                colors=colors, exception_formatter=_console_traceback(colors=colors)
            )
        )

    def logger_factory(*args: Any) -> _NamedWriteLogger:
        return _NamedWriteLogger(stream, str(args[0]) if args else _DEFAULT_NAME)

    with _installed.lock:
        structlog.configure(
            processors=processors,
            # Below the level, a log method is a bare `return None`: a debug call with
            # decoded frame fields costs nothing at info.
            wrapper_class=structlog.make_filtering_bound_logger(levelno),
            logger_factory=logger_factory,
            context_class=dict,
            # No caching: a module-level logger must follow a later configure_logging
            # (tests reconfigure; a cached logger would keep an old stream and level).
            # The price is about a microsecond per call.
            cache_logger_on_first_use=False,
        )
        root = logging.getLogger()
        if _installed.handler is not None:
            root.removeHandler(_installed.handler)
        _installed.handler = _StdlibToStructlog()
        root.addHandler(_installed.handler)
        root.setLevel(levelno)
        limiter.on_hold = _tell_listeners
        _installed.limiter = limiter
        _installed.levelno = levelno


def _console_traceback(*, colors: bool) -> Callable[[TextIO, Any], None]:
    """rich's traceback if rich is installed, imported at the first exception shown
    (the daemon imports structlog blind to rich: `leanimports`); else the plain one."""

    def render(sio: TextIO, exc_info: Any) -> None:
        try:
            from rich.console import Console
            from rich.traceback import Traceback
        except ImportError:
            structlog.dev.plain_traceback(sio, exc_info)
            return
        sio.write("\n")
        console = Console(file=sio, color_system="truecolor" if colors else None, width=100)
        console.print(Traceback.from_exception(*exc_info, show_locals=True))

    return render


def flush_rate_limited(*, everything: bool = False) -> int:
    """Log the count of repeats no later event has reported; returns how many lines.

    Call it about once a second (a burst that stops is then reported within a window
    of its start) and with ``everything=True`` at exit, so no count is lost.
    """
    limiter = _installed.limiter
    if limiter is None:
        return 0
    summaries = limiter.pending(everything=everything)
    for summary in summaries:
        name = str(summary.pop("logger", _DEFAULT_NAME))
        levelno = _METHOD_LEVELS.get(str(summary.pop("level", "warning")), logging.WARNING)
        event = str(summary.pop("event", ""))
        summary[_SUMMARY] = True
        structlog.get_logger(name).log(levelno, event, **summary)
    return len(summaries)


def logs_at(level: int) -> bool:
    """Whether a line at `level` is written (as `configure_logging` set it; without it,
    True: whoever configured structlog decides). For a caller whose fields cost more
    to build than the question: a debug line per frame, under a flood of frames."""
    levelno = _installed.levelno
    return levelno is None or level >= levelno


def rate_limited_due_in() -> float | None:
    """Seconds until `flush_rate_limited` has a count to report (None: none held back)."""
    limiter = _installed.limiter
    return None if limiter is None else limiter.due_in()


def reset_logging() -> None:
    """Undo `configure_logging`: structlog defaults, our `logging` handler removed."""
    with _installed.lock:
        if _installed.handler is not None:
            logging.getLogger().removeHandler(_installed.handler)
            logging.getLogger().setLevel(logging.WARNING)  # the standard library's default
        _installed.handler = None
        _installed.limiter = None
        _installed.levelno = None
        structlog.reset_defaults()
    with _loss.lock:
        _loss.stream, _loss.error, _loss.lines = None, "", 0
