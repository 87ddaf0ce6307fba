"""Which winch produced exported casts, and whether they were simulated, in one phrase.

Every export says it (a CSV header comment, GeoJSON properties, NetCDF global
attributes) so that a simulated cast is never taken for a real one once it has
left the journal. Pure: casts in, words out.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

from cc_daemon.store.records import CastRecord

UNKNOWN = "unknown"  # journals written before the winch was recorded (schema < 3)


class Provenance(NamedTuple):
    winch_backend: str  # "gpio", "sim", "gpio-mock", several joined by ", ", or "unknown"
    simulated: str  # "yes", "no", "mixed" or "unknown"

    def comment(self) -> str:
        return f"# winch_backend: {self.winch_backend}; simulated: {self.simulated}"


def simulated_word(value: bool | None) -> str:
    return UNKNOWN if value is None else ("yes" if value else "no")


def of_casts(casts: Iterable[CastRecord]) -> Provenance:
    backends: set[str] = set()
    flags: set[str] = set()
    for cast in casts:
        backends.add(cast.winch_backend or UNKNOWN)
        flags.add(simulated_word(cast.simulated))
    if not flags:
        return Provenance(UNKNOWN, UNKNOWN)
    simulated = flags.pop() if len(flags) == 1 else "mixed"
    return Provenance(", ".join(sorted(backends)), simulated)
