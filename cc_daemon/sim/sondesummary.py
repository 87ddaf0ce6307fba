"""The simulated survey's sonde lines: per cast, the values at the surface and the bottom.

This module owns the lines `--simulate`'s summary prints under its table when
the journal holds sonde readings: one line per cast (and its station) with its surface reading
(the shallowest within 1 m) and its bottom reading (the deepest), each value
with its unit, and how many readings were missing. It reads the journal
read-only and prints nothing itself.
"""

from __future__ import annotations

from pathlib import Path

from cc_daemon.export.sonde import parameter_map, surface_and_bottom
from cc_daemon.store import JournalReader
from cc_daemon.store.sonde import SondeSampleRecord
from cc_daemon.store.stations import names


def _values(reading: SondeSampleRecord, units: dict[str, str], depth_name: str) -> str:
    parts = [f"{reading.sonde_depth_m:.2f} m"]
    for name, value in reading.values.items():
        if name == depth_name:
            continue
        unit = units.get(name, "")
        unit = "" if unit in ("", "1") else f" {unit}"
        parts.append(f"{name} {'-' if value is None else f'{value:.2f}'}{unit}")
    return ", ".join(parts)


def sonde_lines(db: Path, survey: int | None) -> list[str]:
    """One line per cast of this run (its session) that has sonde readings; none
    without readings."""
    with JournalReader(db, survey=survey) as reader:
        samples = reader.sonde_samples()
        if not samples:
            return []
        units = {c.name: c.unit for c in parameter_map(reader.events())}
        casts = reader.casts()
        named = names(reader.stations())
    lines = []
    for cast in casts:
        mine = [s for s in samples if s.cast_id == cast.id]
        surface, bottom = surface_and_bottom(mine)
        if bottom is None:
            continue
        missing = sum(1 for s in mine if s.status not in ("ok",))
        simulated = " (simulated sonde)" if any(s.simulated for s in mine) else ""
        # A station refused with the probe not home is journaled as a cast that never
        # planned a depth: its readings are where the probe hung, not a profile.
        what = ", refused: the probe held where it stranded" if cast.planned_depth_m <= 0 else ""
        where = f" ({named[cast.id]}{what})" if cast.id in named else ""
        head = f"cast {cast.id}{where} sonde{simulated}: {len(mine)} readings, {missing} incomplete"
        top = "surface: none within 1 m" if surface is None else "surface " + _values(
            surface, units, "depth"
        )  # fmt: skip
        lines.append(f"{head}; {top}; bottom {_values(bottom, units, 'depth')}")
    return lines
