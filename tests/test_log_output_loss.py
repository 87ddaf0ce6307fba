"""A log stream that fails for good (EIO, EPIPE) never raises into the daemon."""

from __future__ import annotations

import errno
import io
import os

import structlog

from cc_daemon.ground.logsetup import (
    add_pending_listener,
    configure_logging,
    output_loss,
    remove_pending_listener,
)


class DeadTerminal(io.StringIO):
    """A stream whose writes fail as a hung-up terminal's do."""

    def __init__(self, error: int) -> None:
        super().__init__()
        self.error = error
        self.fails = True

    def write(self, text: str) -> int:
        if self.fails:
            raise OSError(self.error, os.strerror(self.error))
        return super().write(text)


def test_eio_on_the_log_stream_is_counted_not_raised() -> None:
    stream = DeadTerminal(errno.EIO)
    configure_logging("json", "info", stream)
    log = structlog.get_logger("test")
    assert output_loss() is None
    told: list[int] = []
    listener = lambda: told.append(1)  # noqa: E731
    add_pending_listener(listener)  # the daemon's housekeeping, asleep
    try:
        log.error("first")
        log.info("second")
        log.warning("third")
    finally:
        remove_pending_listener(listener)
    assert told == [1]  # woken once, for the loss: the lines after it are no news
    loss = output_loss()
    assert loss is not None
    assert loss.lines == 3
    assert "Input/output error" in loss.error


def test_epipe_on_a_real_pipe_is_survived_and_the_pipe_replaced() -> None:
    read_end, write_end = os.pipe()
    stream = os.fdopen(write_end, "w")
    try:
        configure_logging("json", "info", stream)
        os.close(read_end)  # the reader left
        log = structlog.get_logger("test")
        log.error("nobody reads this")
        log.error("nor this")
        loss = output_loss()
        assert loss is not None and "BrokenPipeError" in loss.error and loss.lines == 2
        # The descriptor now points at /dev/null: the last flush at exit cannot fail.
        stream.write("x" * 10_000)
        stream.flush()
    finally:
        stream.close()


def test_a_new_configuration_on_a_working_stream_logs_again() -> None:
    configure_logging("json", "info", DeadTerminal(errno.EIO))
    structlog.get_logger("test").error("lost")
    assert output_loss() is not None
    good = io.StringIO()
    configure_logging("json", "info", good)
    structlog.get_logger("test").error("seen")
    assert '"seen"' in good.getvalue()
