"""The field page's log: the daemon's format and level, and one line a minute at most
for any warning or error that repeats (a flood of refused connections, of wrong
passwords, of requests aiohttp cannot parse), the repeats counted in the next line.

This module owns the web process's logging set-up, its flushing of held-back
counts, and the event loop's exception handler (asyncio's own would write one
traceback per failure). It decides nothing else; callers log with structlog.
"""

from __future__ import annotations

import asyncio
import sys
from typing import Any

import structlog

from cc_daemon.ground.logsetup import (
    configure_logging,
    flush_rate_limited,
    rate_limited_due_in,
    resolve_format,
)

log = structlog.get_logger("cc_daemon.cli.web")

WINDOW_S = 60.0  # repeats of a line are held back this long, then counted


def configure(fmt: str, level: str) -> None:
    """As the daemon: "auto" follows stdout (a terminal, or journald's JSON)."""
    configure_logging(
        resolve_format(fmt, sys.stdout), level, sys.stderr, rate_limit_window_s=WINDOW_S
    )


async def flush_forever() -> None:
    """Log the counts held back, when each is due."""
    while True:
        due = rate_limited_due_in()
        await asyncio.sleep(WINDOW_S if due is None else min(max(due, 0.1), WINDOW_S))
        flush_rate_limited()


def loop_error(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
    """The loop's exception handler: through the rate limiter, like every other line."""
    exc = context.get("exception")
    log.error(
        f"asyncio: {context.get('message', 'an error in the event loop')}",
        error=type(exc).__name__ if exc is not None else None,
        exc_info=exc,
    )
