"""Test kit for the lake floor: lines surveys written straight into real journals.

The simulator's models (`sim.bathysurvey`) write the soundings on a fake clock, so
a survey of several hundred metres of lines is a real journal in a second or two;
its `SurveyTruth` says what each reading was, and its mission's field is the bed.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from cc_daemon.sim.bathysurvey import SurveyTruth, write_lines_survey
from cc_daemon.sim.echosounder import EchoErrors
from cc_daemon.sim.lines import make_lines_mission
from cc_daemon.sim.mission import from_lat_lon
from cc_daemon.store import Journal
from cc_daemon.store.synthetic import FakeClock

ERRORS = EchoErrors(outlier_rate=0.03, dropout_rate=0.05)
AUTOPILOT_DRAFT_M = 0.10
ONBOARD_DRAFT_M = 0.15


def lines_journal(
    db: Path,
    *,
    lines: int = 6,
    line_length_m: float = 150.0,
    spacing_m: float = 20.0,
    seed: int = 1,
    simulated: bool | None = True,
    **survey: Any,
) -> SurveyTruth:
    """A real journal at `db` holding one lines survey; its truth."""
    clock = FakeClock()
    backend = None if simulated is None else ("sim" if simulated else "gpio")
    journal = Journal(
        db, monotonic=clock.monotonic, wall=clock.wall, winch_backend=backend, simulated=simulated
    )
    journal.open()
    try:
        mission = make_lines_mission(
            3, seed, spacing_m=spacing_m, lines=lines, line_length_m=line_length_m
        )
        options: dict[str, Any] = {
            "errors": ERRORS,
            "autopilot_draft_m": AUTOPILOT_DRAFT_M,
            "onboard_draft_m": ONBOARD_DRAFT_M,
            "seed": seed,
            **survey,
        }
        truth = write_lines_survey(journal, clock, mission, **options)
        deadline = time.monotonic() + 60
        while journal.health().pending_rows and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        journal.close()
    return truth


def true_depth(truth: SurveyTruth, crs: Any, x: Any, y: Any) -> Any:
    """The simulator's bed under projected points (`crs`'s metres)."""
    from pyproj import Transformer

    back = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = back.transform(np.asarray(x), np.asarray(y))
    east, north = from_lat_lon(np.asarray(lat), np.asarray(lon))
    return truth.mission.field.depth_xy(east, north, np)
