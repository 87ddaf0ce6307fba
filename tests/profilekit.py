"""Test kit for the profiles' products: a real journal of simulated sonde casts.

`write_journal` writes a survey journal (a real SQLite file, through the
journal's own writer) whose casts carry the readings of `sim.profilecast`
(known water, the simulated sonde's lags and noise), each with its phase, the
winch's line out, the plan the daemon would have journaled (with the sonar
bottom and the profile's resolution) and the map's `sonde_started` event.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cc_daemon.config.sonde import DEFAULT_PARAMETERS
from cc_daemon.core.protocol import StartMeasuring
from cc_daemon.science.profiles.process import Series
from cc_daemon.sim.profilecast import CastShape, simulated_cast
from cc_daemon.sim.water import WaterColumn
from cc_daemon.store import Journal

WALL0 = 1.78e9  # 2026-05-28
LAT0_E7, LON0_E7 = 404506308, -37260579


@dataclass(frozen=True, slots=True)
class CastSpec:
    water: WaterColumn = field(default_factory=WaterColumn)
    seed: int = 0
    shape: CastShape = field(default_factory=CastShape)
    north_m: float = 0.0  # the station, metres north of the first
    sonar_m: float | None = 8.0  # the bottom the cast was planned on; None: cast blind
    mode: str = "continuous"
    resolve: list[str] | None = None  # the plan's profile.resolve; None: not recorded


def phases(series: Series) -> list[str]:
    """What the daemon labels each reading: from the winch's motion and the soak."""
    moved = np.gradient(series.line_out_m, series.time_s)
    soak = series.soaking if series.soaking is not None else np.zeros(len(moved), bool)
    labels = []
    for speed, soaking in zip(moved, soak, strict=True):
        if soaking:
            labels.append("soaking")
        elif speed > 1e-6:
            labels.append("descending")
        elif speed < -1e-6:
            labels.append("ascending")
        else:
            labels.append("dwelling")
    return labels


def write_journal(
    path: Path, casts: Sequence[CastSpec], *, response_times: bool = True
) -> list[Series]:
    """The journal at `path` with `casts`; returns each cast's series as written."""
    journal = Journal(path)
    journal.open()
    parameters = [p.model_dump(by_alias=True, mode="json") for p in DEFAULT_PARAMETERS]
    if not response_times:  # a journal written before response times were configured
        for p in parameters:
            del p["response_s"]
    journal.record_event("sonde_started", backend="sim", depth_parameter="depth",
                         parameters=parameters)  # fmt: skip
    written = []
    t0 = 100.0
    for number, spec in enumerate(casts):
        lat_e7 = LAT0_E7 + round(spec.north_m / 111_195 * 1e7)
        sonar_mm = 0 if spec.sonar_m is None else round(spec.sonar_m * 1000)
        station = StartMeasuring(number, LON0_E7, lat_e7, 0, sonar_mm, 100)
        plan: dict[str, object] = {
            "depth_m": spec.shape.depth_m,
            "water_depth_m": spec.sonar_m,
            "mode": spec.mode,
            "profile": {"bin_m": 0.25, "min_count": 2, "descent_limit_m_s": 0.125},
        }
        if spec.resolve is not None:
            plan["profile"] = {**plan["profile"], "resolve": spec.resolve}  # type: ignore[dict-item]
        cast_id = journal.start_cast(
            station, planned_depth_m=spec.shape.depth_m, mode=spec.mode, plan=plan
        )
        series = simulated_cast(spec.shape, spec.water, seed=spec.seed)
        for i, phase in enumerate(phases(series)):
            values: dict[str, float | None] = {
                name: float(v[i]) for name, v in series.values.items()
            }
            journal.record_sonde_sample(
                cast_id=cast_id, phase=phase, mono_s=t0 + float(series.time_s[i]),
                wall_s=WALL0 + t0 + float(series.time_s[i]), duration_s=0.08, status="ok",
                error=None, line_out_m=float(series.line_out_m[i]),
                sonde_depth_m=float(series.depth_m[i]), values=values, missing={},
                simulated=True,
            )  # fmt: skip
        journal.end_cast(cast_id, outcome="completed", reached_depth_m=spec.shape.depth_m)
        written.append(series)
        t0 += float(series.time_s[-1]) + 300.0
    journal.close()
    return written
