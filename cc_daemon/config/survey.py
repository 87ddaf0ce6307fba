"""[survey]: how the soundings of a survey are corrected and judged for the map.

`cc-daemon map` reads these (the daemon never does): each echosounder's draft
(its transducer's depth below the water line, added to every reading it gives),
and the quality control's thresholds (docs/maps.md). It must never import the
science floor: validating a configuration stays cheap.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, Field

from cc_daemon.config.rules import _SECTION, _Positive

_Draft = Annotated[float, Field(ge=0, le=5)]


class SurveySettings(BaseModel):
    """[survey]: the soundings' corrections and quality control, for `cc-daemon map`."""

    model_config = _SECTION

    # Each source's transducer below the water line, metres (0 to 5): the autopilot's
    # sonar (its P-T and P-M frames) and the companion computer's own Ping1D ([sonar]).
    autopilot_draft_m: _Draft = 0.0
    onboard_draft_m: _Draft = 0.0
    # A reading less confident than this is not used, percent (0 to 100).
    min_confidence_pct: Annotated[int, Field(ge=0, le=100)] = 50
    # A fix reached and left faster than this is a GPS glitch, m/s.
    max_speed_m_s: _Positive = 10.0
    # A Ping1D reading is placed on the track only between two fixes this close in time, s.
    max_gap_s: _Positive = 3.0
    # Who made the map, for its metadata (the NetCDF grid's ACDD 1.3 attributes, which a
    # data server such as ERDDAP shows); empty: left out, and `cc-daemon map` says so.
    creator_name: str = ""
    creator_email: str = ""
    creator_url: str = ""
    institution: str = ""
    project: str = ""
    license: str = ""
