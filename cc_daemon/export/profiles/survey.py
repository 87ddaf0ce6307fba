"""A survey's sonde readings made into profiles: from the journal's records to the science.

This module owns the journal's side of `cc-daemon profiles`: which readings a
profile takes (the cast's `ok` and `partial` readings with a pressure depth, in
time order; a `late` or failed reading never), each parameter's response time
(from the map the daemon journaled, else the shipped map's for the same name and
unit, else none: said in `notes`), the bins (the option, else what the casts were
planned for, else `profile.bin_m`'s default), which parameters are the
temperature, the oxygen and the chlorophyll, and the bed under each station (the
sonar bottom the cast was planned on). It hands arrays to `cc_daemon.science` and
keeps what comes back with its cast. It never reads the journal or a file itself.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from cc_daemon.config.profile import ProfileSettings
from cc_daemon.config.sonde import DEFAULT_PARAMETERS
from cc_daemon.export.sonde import Column, parameter_map
from cc_daemon.science.hypsography import Hypsography
from cc_daemon.science.profiles.binning import bin_index
from cc_daemon.science.profiles.derived import Reading, Roles, read_profile
from cc_daemon.science.profiles.lag import Method
from cc_daemon.science.profiles.process import Processed, Series, Settings, process
from cc_daemon.store.records import CastRecord, EventRecord
from cc_daemon.store.sonde import SondeSampleRecord

USABLE = ("ok", "partial")  # a reading's statuses a profile takes
_DEFAULTS = ProfileSettings()


@dataclass(frozen=True, slots=True)
class ProfiledCast:
    """One cast: its record, the readings its profiles were made of (in time order, as
    `series`), what the processing made of them, and what they say."""

    cast: CastRecord
    readings: list[SondeSampleRecord]
    series: Series
    processed: Processed
    reading: Reading

    @property
    def bed_m(self) -> float | None:
        """The bottom under the station the cast was planned on (None: cast blind)."""
        found = self.cast.plan.get("water_depth_m")
        return float(found) if isinstance(found, int | float) else None


@dataclass(frozen=True, slots=True)
class Survey:
    casts: list[ProfiledCast]
    columns: list[Column]  # the parameters profiled, in map order (the depth's left out)
    settings: Settings
    lake: Hypsography | None
    notes: list[str] = field(default_factory=list)

    @property
    def simulated(self) -> bool:
        return any(r.simulated for c in self.casts for r in c.readings)


def _journaled_map(events: Iterable[EventRecord]) -> tuple[dict[str, Any], str | None]:
    """Each parameter's journaled table (the last `sonde_started`), and the depth's name."""
    tables: dict[str, Any] = {}
    depth: str | None = None
    for event in events:
        listed = event.detail.get("parameters")
        if event.kind == "sonde_started" and isinstance(listed, list):
            tables = {str(p.get("name")): p for p in listed if isinstance(p, dict)}
            named = event.detail.get("depth_parameter")
            depth = named if isinstance(named, str) else None
    return tables, depth


def response_times(
    columns: Sequence[Column], tables: dict[str, Any], notes: list[str]
) -> dict[str, float]:
    shipped = {(p.name, p.unit): p.response_s for p in DEFAULT_PARAMETERS}
    found: dict[str, float] = {}
    guessed: list[str] = []
    for c in columns:
        given = tables.get(c.name, {}).get("response_s")
        if isinstance(given, int | float) and math.isfinite(given) and given >= 0:
            found[c.name] = float(given)
        elif (c.name, c.unit) in shipped:
            found[c.name] = shipped[(c.name, c.unit)]
            if shipped[(c.name, c.unit)] > 0:
                guessed.append(f"{c.name} {found[c.name]:g} s")
        else:
            found[c.name] = 0.0
    if guessed:
        notes.append(
            "the journal holds no response times (written before they were configured): "
            f"the shipped map's are used ({', '.join(guessed)})"
        )
    return found


def lag_method(casts: Sequence[CastRecord], notes: list[str]) -> Method:
    """`inverse`, or `none` when every cast that says what it was planned to resolve
    says nothing (`profile.resolve = []`, as the simulator's fast pace plans them): its
    descent was not slowed for any sensor, the readings lie too far apart for a lag to
    be taken out (at 1.25 m a reading, the inverse drew water warmer than any
    there), and a corrected profile would overstate."""
    said = [
        c.plan["profile"].get("resolve") for c in casts if isinstance(c.plan.get("profile"), dict)
    ]
    if said and all(r == [] for r in said):
        notes.append(
            "sensor lags not corrected: the casts were planned to resolve no sensor's lag"
            " (profile.resolve = []), their readings too far apart to take one out"
            " (--lag-correction inverse corrects them all the same)"
        )
        return "none"
    return "inverse"


def _planned(casts: Sequence[CastRecord], key: str) -> set[Any]:
    found = set()
    for cast in casts:
        profile = cast.plan.get("profile")
        if isinstance(profile, dict) and isinstance(profile.get(key), int | float):
            found.add(profile[key])
    return found


def _choose(given: Any, planned: set[Any], default: Any, what: str, notes: list[str]) -> Any:
    if given is not None:
        return given
    if len(planned) == 1:
        return planned.pop()
    if planned:
        chosen = min(planned)
        notes.append(f"the casts were planned for several {what} ({sorted(planned)}): {chosen}")
        return chosen
    return default


def _named(columns: Sequence[Column], name: str, standard: str, unit: str | None) -> str | None:
    for c in columns:
        if (c.name == name or c.standard_name == standard) and (unit is None or c.unit == unit):
            return c.name
    return None


def roles(columns: Sequence[Column]) -> Roles:
    """Which parameters are the temperature (°C), the oxygen (mg/L) and the chlorophyll."""
    return Roles(
        temperature=_named(columns, "temperature", "sea_water_temperature", "degC"),
        oxygen=_named(
            columns, "do_concentration", "mass_concentration_of_oxygen_in_sea_water", "mg/L"
        ),
        chlorophyll=_named(
            columns, "chlorophyll", "mass_concentration_of_chlorophyll_a_in_sea_water", None
        ),
    )


def _series(readings: Sequence[SondeSampleRecord], names: Sequence[str]) -> Series:
    nan = math.nan
    return Series(
        time_s=np.array([r.mono_s for r in readings]),
        depth_m=np.array([r.sonde_depth_m for r in readings], dtype=np.float64),
        line_out_m=np.array(
            [nan if r.line_out_m is None else r.line_out_m for r in readings], dtype=np.float64
        ),
        values={
            name: np.array(
                [nan if (v := r.values.get(name)) is None else v for r in readings],
                dtype=np.float64,
            )
            for name in names
        },
        soaking=np.array([r.phase == "soaking" for r in readings]),
    )


def profile_survey(
    casts: Sequence[CastRecord],
    samples: Sequence[SondeSampleRecord],
    events: Iterable[EventRecord],
    *,
    bin_m: float | None = None,
    method: Method | None = None,
    lake: Hypsography | None = None,
) -> Survey:
    """The casts' profiles on one grid of bins, and what each says. Raises ValueError
    when no cast has a reading to make a profile of. `method` None: `inverse`, unless
    the casts were planned to resolve no sensor's lag (`lag_method`)."""
    events = list(events)
    notes: list[str] = []
    if method is None:
        method = lag_method(casts, notes)
    tables, depth_name = _journaled_map(events)
    every = parameter_map(events, samples)
    depth_name = depth_name or _named(every, "depth", "depth", None)
    columns = [c for c in every if c.name != depth_name]
    settings = Settings(
        bin_m=_choose(bin_m, _planned(casts, "bin_m"), _DEFAULTS.bin_m, "bins", notes),
        min_count=_choose(
            None, _planned(casts, "min_count"), _DEFAULTS.min_count, "least readings", notes
        ),
        response_s=response_times(columns, tables, notes),
        method=method,
    )
    usable: dict[int, list[SondeSampleRecord]] = {c.id: [] for c in casts}
    for s in samples:
        if s.cast_id in usable and s.status in USABLE and s.sonde_depth_m is not None:
            usable[s.cast_id].append(s)
    kept = [(c, sorted(usable[c.id], key=lambda r: r.mono_s)) for c in casts]
    for cast, readings in kept:
        if cast.outcome != "skipped-shallow" and len(readings) < 2:
            notes.append(f"cast {cast.id}: no profile ({len(readings)} usable sonde readings)")
    kept = [(c, r) for c, r in kept if len(r) >= 2]
    if not kept:
        raise ValueError("no cast has sonde readings with a depth to make profiles of")
    deepest = max(r.sonde_depth_m or 0.0 for _, readings in kept for r in readings)
    shallowest = min(r.sonde_depth_m or 0.0 for _, readings in kept for r in readings)
    bins = range(
        min(int(bin_index(shallowest, settings.bin_m)), 0),
        int(bin_index(deepest, settings.bin_m)) + 1,
    )
    names = [c.name for c in columns]
    chosen = roles(columns)
    profiled = []
    for cast, readings in kept:
        series = _series(readings, names)
        done = process(series, replace(settings, stepped=cast.mode == "stepped"), bins=bins)
        profiled.append(
            ProfiledCast(cast, readings, series, done, read_profile(done.down, chosen, lake))
        )
    return Survey(profiled, columns, settings, lake, notes)
