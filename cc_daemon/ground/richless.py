"""structlog without rich: the service's log is JSON lines, not a terminal.

structlog's `dev` module (imported by `import structlog`) imports rich and
pygments when they are installed, for pretty tracebacks on a console: about
30 ms and 4 MiB the daemon logging JSON never uses. This module owns importing
structlog blind to rich, once, before anything else imports it; the console
renderer then asks for rich itself, only when it formats an exception
(`logsetup`). It must never hide rich from anyone else: the block lasts the one
import.
"""

from __future__ import annotations

import sys


def import_structlog_without_rich() -> None:
    """Import structlog (and its dev module) so that it does not import rich.

    Does nothing if structlog or rich is already imported: a process that has
    them pays nothing more and keeps rich's tracebacks.
    """
    if "structlog" in sys.modules or "rich" in sys.modules:
        return
    sys.modules["rich"] = None  # type: ignore[assignment]  # `import rich` raises ImportError
    try:
        import structlog.dev  # noqa: F401
    finally:
        del sys.modules["rich"]
