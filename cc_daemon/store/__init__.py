"""The survey journal: a SQLite file holding every fix, cast, sample and event.

Import from here. `Journal` (`journal`: what is recorded) is the write side the
daemon uses from its event loop, on top of `writer` (the writer thread and
SQLite transactions), `buffer` (the bounded rows in memory) and `failures`
(what a storage error means, logging that never raises); `JournalReader` is the
read side for the `casts`, `export` and `plot` commands (imported when first
named: the daemon never reads); `schema` owns the file layout and its
migrations. Nothing in this package imports asyncio: the journal's thread is
invisible to its callers.
"""

from typing import TYPE_CHECKING, Any

from cc_daemon.store.health import JournalHealth
from cc_daemon.store.journal import (
    OUTCOMES,
    PHASES,
    Journal,
    default_store_path,
)
from cc_daemon.store.schema import SCHEMA_VERSION, StoreError

if TYPE_CHECKING:
    from cc_daemon.store.reader import JournalReader
    from cc_daemon.store.records import (
        CastRecord,
        EventRecord,
        FixRecord,
        SampleRecord,
    )

# The read side, imported when first asked for: the daemon writes and never reads
# (docs/performance.md).
_READER = frozenset({"CastRecord", "EventRecord", "FixRecord", "JournalReader", "SampleRecord"})


def __getattr__(name: str) -> Any:
    if name in _READER:
        from cc_daemon.store import reader

        return getattr(reader, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "OUTCOMES",
    "PHASES",
    "SCHEMA_VERSION",
    "CastRecord",
    "EventRecord",
    "FixRecord",
    "Journal",
    "JournalHealth",
    "JournalReader",
    "SampleRecord",
    "StoreError",
    "default_store_path",
]
