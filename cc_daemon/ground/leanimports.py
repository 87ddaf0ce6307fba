"""The daemon's imports without the optional extras it never uses.

Two libraries import heavy optional modules when they find them installed:
asyncio imports ssl (libssl and libcrypto: about 4.5 MiB of resident memory)
for TLS connections, and structlog's `dev` module imports rich and pygments
(about 30 ms and 4 MiB) for pretty tracebacks on a console. The daemon makes
no TLS connection and logs JSON lines to journald; the console renderer asks
for rich itself, only when it shows an exception (`logsetup`).

pydantic looks for plugins each time it builds a model's validator: the
first time it imports `importlib.metadata` (with email, zipfile, csv and
tempfile: some 20 ms) and reads the entry points of every installed
distribution. The daemon builds all its models at start (the configuration's
sections) and wants no third-party code hooking its configuration's
validation: while they are built, `pydantic_without_plugins` hands pydantic a
loader that finds none, as `PYDANTIC_DISABLE_PLUGINS=__all__` would, without
the import or the scan.

This module owns importing such a library once, before anything else does,
with the extras looking absent, so the library takes its own no-extra path. It
must never hide a module from anyone else: each block lasts the one import,
and a module someone already imported is never hidden.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
import types
from collections.abc import Iterable, Iterator


def import_blind_to(module: str, hidden: Iterable[str]) -> None:
    """Import `module` while importing any of `hidden` raises ImportError.

    Does nothing if `module` or one of `hidden` is already imported: that
    process pays nothing more and keeps the extra.
    """
    hidden = tuple(hidden)
    if module in sys.modules or any(name in sys.modules for name in hidden):
        return
    for name in hidden:
        sys.modules[name] = None  # type: ignore[assignment]  # `import name` raises ImportError
    try:
        importlib.import_module(module)
    finally:
        for name in hidden:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]


def import_daemon_libraries_lean() -> None:
    """asyncio without ssl, structlog without rich: first thing in the daemon's run."""
    import_blind_to("asyncio", ("ssl",))  # the daemon opens no TLS connection
    import_blind_to("structlog.dev", ("rich",))  # the service logs JSON lines


_PLUGIN_LOADER = "pydantic.plugin._loader"


@contextlib.contextmanager
def pydantic_without_plugins() -> Iterator[None]:
    """Models built inside the block find no pydantic plugin, and cost no plugin search.

    pydantic asks `pydantic.plugin._loader.get_plugins()` for every validator it
    builds; inside the block that module is a stand-in whose answer is none. After
    it, the real loader is pydantic's again for anything built later. Does nothing
    if the real loader was already imported (the search is paid for by then).
    """
    if _PLUGIN_LOADER in sys.modules:
        yield
        return
    stand_in = types.ModuleType(
        _PLUGIN_LOADER, "No pydantic plugins: see cc_daemon.ground.leanimports"
    )
    stand_in.get_plugins = lambda: ()  # type: ignore[attr-defined]
    sys.modules[_PLUGIN_LOADER] = stand_in
    try:
        yield
    finally:
        if sys.modules.get(_PLUGIN_LOADER) is stand_in:
            del sys.modules[_PLUGIN_LOADER]
