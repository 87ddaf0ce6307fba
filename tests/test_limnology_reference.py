"""Our limnology against rLakeAnalyzer's own answers, to 1e-6 (fixtures; R never runs).

tests/fixtures/rlakeanalyzer/README.md says how the answers were made: rLakeAnalyzer
1.12.0 on its example data, its help pages' examples, profiles made to reach its
corners, and ten binned profiles of our own processing.
"""

from __future__ import annotations

import math

import pytest

from tests.fixtures.rlakeanalyzer.ours import binned_profiles
from tests.fixtures.rlakeanalyzer.reference import QUANTITIES, cases, compare, lakes, ours

TOLERANCE = 1e-6


@pytest.mark.parametrize("selection", ["sparkling", "help", "edges", "cc_daemon"])
def test_every_quantity_agrees_with_the_reference(selection: str) -> None:
    worst, compared = compare(selection)
    assert compared == {"sparkling": 200, "help": 2, "edges": 7, "cc_daemon": 10}[selection]
    assert worst == pytest.approx(dict.fromkeys(worst, 0.0), abs=TOLERANCE)


def test_the_fixtures_reach_the_answers_that_matter() -> None:
    """Not a file of NaNs: the reference's corners are all there to be agreed with."""
    found = {(c.set, c.profile): c.expected for c in cases()}
    assert math.isnan(found[("edges", "mixed")]["thermo_depth"])
    assert found[("edges", "three_depths")]["thermo_depth"] == 1.0
    two = found[("edges", "two_thermoclines")]
    assert two["thermo_depth_seasonal"] > two["thermo_depth"] + 4  # a deeper, seasonal one
    assert found[("help", "schmidt")]["schmidt_stability"] == pytest.approx(23.7696, abs=1e-4)
    sparkling = [c.expected for c in cases() if c.set == "sparkling"]
    assert sum(math.isfinite(e["schmidt_stability"]) for e in sparkling) == 200
    assert sum(e["thermo_depth_seasonal"] != e["thermo_depth"] for e in sparkling) >= 10


def test_a_wrong_answer_would_be_seen() -> None:
    """The comparison is no rubber stamp: the seasonal and the plain thermocline differ on
    the help page's profile, and a lake of another shape gives another stability."""
    (case,) = [c for c in cases() if (c.set, c.profile) == ("help", "thermo_meta")]
    got = ours(case, None)
    assert abs(got["thermo_depth"] - case.expected["thermo_depth_seasonal"]) > 1.0
    (schmidt,) = [c for c in cases() if (c.set, c.profile) == ("help", "schmidt")]
    depths, areas = lakes()["schmidt_help"]
    wider = ours(
        schmidt, (depths, [a * 1.1 if d > 3 else a for d, a in zip(depths, areas, strict=True)])
    )
    assert abs(wider["schmidt_stability"] - schmidt.expected["schmidt_stability"]) > 1e-3
    assert set(QUANTITIES) <= set(got)


def test_our_ten_profiles_are_what_the_processing_makes_today() -> None:
    """The fixtures' binned profiles are the processing's: if it changes, make them again
    (README.md beside them) so the reference judges what we publish."""
    kept = {c.profile: c for c in cases() if c.set == "cc_daemon"}
    made = binned_profiles()
    assert [name for name, _, _ in made] == list(kept)
    for name, depths, temps in made:
        assert depths == pytest.approx(kept[name].depth_m, abs=1e-9), name
        assert temps == pytest.approx(kept[name].temperature_c, abs=1e-9), name
