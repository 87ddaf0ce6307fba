"""The lake floor's science, pure: each step against a truth it must meet.

Arrays made here, with their answers known: a plane the interpolators must give
back exactly, a bowl whose volume is known in closed form, lines whose spacing is
known, outliers and a GPS glitch put where the quality control must find them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("scipy")
pytest.importorskip("contourpy")

from cc_daemon.science.bathymetry import interpolate, qc, spacing
from cc_daemon.science.bathymetry.blocks import GridSpec, block_median
from cc_daemon.science.bathymetry.contours import contours, levels
from cc_daemon.science.bathymetry.grid import make_grid
from cc_daemon.science.bathymetry.validation import block_kfold
from cc_daemon.science.hypsography import Hypsography

E0, N0 = 438_000.0, 4_478_000.0  # UTM-sized coordinates: the arithmetic must hold there


def lines(spacing_m: float = 20.0, count: int = 6, length_m: float = 200.0, step_m: float = 0.5):
    """Boustrophedon lines as one track: x, y, segment (one pass)."""
    xs, ys = [], []
    for i in range(count):
        along = np.arange(0.0, length_m + 1e-9, step_m)
        xs.append(along if i % 2 == 0 else along[::-1])
        ys.append(np.full(len(along), i * spacing_m))
    return E0 + np.concatenate(xs), N0 + np.concatenate(ys), np.zeros(sum(map(len, xs)), np.int64)


def plane(x, y):
    return 3.0 + 0.01 * (x - E0) - 0.02 * (y - N0)


def test_screen_names_the_first_rule_that_holds() -> None:
    distance = np.array([5.0, 0.0, 5.0, 5.0, 0.0])
    confidence = np.array([90.0, 0.0, 30.0, 120.0, 90.0])
    valid = np.array([True, True, True, False, True])
    reasons = qc.screen(distance, confidence, valid, min_confidence_pct=50)
    assert [qc.Reason(r) for r in reasons] == [
        qc.Reason.KEPT, qc.Reason.NO_ECHO, qc.Reason.LOW_CONFIDENCE, qc.Reason.INVALID,
        qc.Reason.NO_ECHO,
    ]  # fmt: skip
    assert qc.counts(reasons) == {
        "kept": 1, "invalid": 1, "no_echo": 2, "low_confidence": 1, "position_jump": 0,
        "off_track": 0, "spike": 0,
    }  # fmt: skip


def test_spikes_finds_second_echoes_and_shallow_returns_on_a_slope_and_spares_the_rest() -> None:
    rng = np.random.default_rng(1)
    n = 4000
    depth = 2.0 + np.linspace(0.0, 6.0, n) + rng.normal(0.0, 0.02, n)  # a steady slope
    bad = rng.choice(n, 120, replace=False)
    depth[bad[:60]] *= 2.0  # second echoes
    depth[bad[60:]] *= rng.uniform(0.25, 0.85, 60)  # fish and weed
    segment = np.repeat([0, 1], n // 2)  # two passes: no window crosses between them
    found = qc.spikes(depth, segment)
    assert found[bad].all()
    good = np.setdiff1d(np.arange(n), bad)
    assert found[good].mean() < 0.005
    # Each segment alone gives the same answer: windows never reach across.
    alone = np.concatenate([qc.spikes(depth[: n // 2], segment[: n // 2]),
                            qc.spikes(depth[n // 2 :], segment[n // 2 :])])  # fmt: skip
    assert (alone == found).all()


def test_position_jumps_are_glitches_not_journeys() -> None:
    t = np.arange(20) * 0.5
    x = t * 1.5
    y = np.zeros(20)
    x[7] += 60.0  # a GPS glitch: there and back in a second
    x[15:] += 500.0  # the boat towed elsewhere: a real move, kept
    jumped = qc.position_jumps(t, x, y, np.zeros(20, np.int64), max_speed_m_s=10.0)
    assert list(np.flatnonzero(jumped)) == [7]
    # A glitch at a segment's very start is judged on its one neighbour.
    x2 = t * 1.5
    x2[0] += 60.0
    assert list(np.flatnonzero(qc.position_jumps(t, x2, y, np.zeros(20, np.int64),
                                                 max_speed_m_s=10.0))) == [0]  # fmt: skip


def test_block_median_reduces_each_cell_to_its_median_depth_and_position() -> None:
    spec = GridSpec(E0, N0, 5.0, 2, 1)
    x = np.array([E0 + 1, E0 + 2, E0 + 4, E0 + 6, E0 + 100])
    y = np.array([N0 + 1, N0 + 3, N0 + 2, N0 + 1, N0 + 1])
    z = np.array([4.0, 9.0, 5.0, 7.0, 1.0])
    blocks = block_median(x, y, z, spec)
    assert list(blocks.cell) == [0, 1] and list(blocks.count) == [3, 1]
    assert list(blocks.depth) == [5.0, 7.0]  # the outlier 9 does not move a median
    assert blocks.x[0] == E0 + 2 and blocks.y[0] == N0 + 2
    assert spec.index(np.array([E0 - 1]), np.array([N0]))[0] == -1


@pytest.mark.parametrize("method", interpolate.METHODS)
def test_every_interpolator_gives_a_plane_back_and_nothing_outside_the_hull(method: str) -> None:
    rng = np.random.default_rng(2)
    x = E0 + rng.uniform(0, 100, 400)
    y = N0 + rng.uniform(0, 100, 400)
    predict = interpolate.fit(x, y, plane(x, y), method)
    qx, qy = E0 + rng.uniform(20, 80, 50), N0 + rng.uniform(20, 80, 50)
    assert predict(qx, qy) == pytest.approx(plane(qx, qy), abs=1e-6)
    assert np.isnan(predict(np.array([E0 + 500.0]), np.array([N0 + 500.0]))).all()


def test_the_barycentric_shortcut_is_scipys_own_arithmetic() -> None:
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(3)
    points = rng.uniform(0, 100, (300, 2))
    ours = Delaunay(points)
    interpolate._barycentric(ours)
    theirs = Delaunay(points)
    assert np.allclose(ours._transform, theirs.transform, atol=1e-9, equal_nan=True)


def test_the_grid_leaves_a_missed_line_empty_and_knows_each_cells_distance() -> None:
    x, y, _segment = lines(count=7)
    keep = np.abs(y - (N0 + 60.0)) > 1.0  # line 4 was never sailed
    x, y = x[keep], y[keep]
    spec = GridSpec.covering(x, y, 5.0)
    grid, _blocks = make_grid(x, y, plane(x, y), spec, max_distance_m=15.0)
    gx, gy = np.meshgrid(spec.x, spec.y)
    mapped = grid.mapped
    assert grid.depth_m[mapped] == pytest.approx(plane(gx, gy)[mapped], abs=1e-6)
    # Between lines 3 and 5 (40 m apart) the middle is 20 m from any sounding: empty.
    middle = np.abs(gy - (N0 + 60.0)) < 3.0
    assert not mapped[middle & (gx > E0 + 20) & (gx < E0 + 180)].any()
    assert mapped[(np.abs(gy - (N0 + 30.0)) < 3.0) & (gx < E0 + 195)].all()
    expected = np.min(np.hypot(gx.ravel()[:, None] - x[None, ::20],
                               gy.ravel()[:, None] - y[None, ::20]), axis=1)  # fmt: skip
    assert (grid.distance_m.ravel() <= expected + 1e-9).all()
    assert grid.covered_fraction < 1.0
    assert grid.count.sum() == len(x)


def test_cross_validation_holds_out_whole_blocks_and_takes_out_the_noise() -> None:
    x, y, _ = lines()
    rng = np.random.default_rng(4)
    truth = plane(x, y)
    spec = GridSpec.covering(x, y, 5.0)
    exact = block_median(x, y, truth, spec)
    cv = block_kfold(exact, block_m=10.0)
    assert cv.rmse_m == pytest.approx(0.0, abs=1e-6) and cv.predicted > 0.8 * len(exact)
    noisy = block_median(x, y, truth + rng.normal(0.0, 0.05, len(x)), spec)
    cv = block_kfold(noisy, block_m=10.0)
    # Each held-out median carries ~0.05 * sqrt(pi/2 / 10) of noise; taken out, what is
    # left is the map's error, far below the raw residuals'.
    assert cv.raw_rmse_m > 0.015 and cv.rmse_m < cv.raw_rmse_m
    assert block_kfold(noisy, block_m=10.0) == cv  # seeded


def test_the_maps_error_is_never_estimated_under_its_bias() -> None:
    # Soundings a little noisy: the held-out medians' noise, taken out, leaves less than
    # the residuals' mean; the estimate stays at the bias, never at a perfect 0.
    x, y, _ = lines()
    rng = np.random.default_rng(0)
    noisy = plane(x, y) + rng.normal(0.0, 0.02, len(x))
    cv = block_kfold(block_median(x, y, noisy, GridSpec.covering(x, y, 5.0)), block_m=10.0)
    assert cv.bias_m != 0.0 and cv.rmse_m >= abs(cv.bias_m) > 0.0
    assert cv.rmse_m <= cv.raw_rmse_m


def test_the_line_spacing_is_read_from_the_track_and_sets_the_rules() -> None:
    for spacing_m in (10.0, 20.0, 50.0):
        x, y, segment = lines(spacing_m=spacing_m, count=6, length_m=300.0)
        found = spacing.line_spacing_m(x, y, segment)
        assert found == pytest.approx(spacing_m, rel=0.05)
    x = E0 + np.arange(0, 500, 0.75)
    assert spacing.line_spacing_m(x, np.full(len(x), N0), np.zeros(len(x), np.int64)) is None
    assert [spacing.cell_m(s) for s in (20.0, 10.0, 50.0, 8.0)] == [5.0, 2.5, 10.0, 2.0]
    assert spacing.max_distance_m(20.0) == 15.0 and spacing.cv_block_m(20.0) == 10.0


def test_hypsography_of_a_grid_by_hand_and_of_a_cone_in_closed_form() -> None:
    h = Hypsography.from_depths(np.array([[1.0, 2.0], [3.0, np.nan]]), 4.0, 1.0, 0.75)
    assert list(h.depth_m) == [0.0, 1.0, 2.0, 3.0]
    assert list(h.area_m2) == [12.0, 8.0, 4.0, 0.0]
    assert list(h.volume_m3) == [24.0, 12.0, 4.0, 0.0]
    assert h.covered_fraction == 0.75
    assert h.rows()[1] == (1.0, 8.0, 12.0)
    # An inverted cone 10 m deep, 100 m in radius: volume pi r^2 h / 3, area at depth
    # z the circle of radius r (1 - z / h).
    cell = 0.5
    c = np.arange(-100, 100, cell) + cell / 2
    gx, gy = np.meshgrid(c, c)
    r = np.hypot(gx, gy)
    bed = np.where(r <= 100.0, 10.0 * (1 - r / 100.0), np.nan)
    cone = Hypsography.from_depths(bed, cell * cell, 1.0)
    assert cone.volume_m3[0] == pytest.approx(math.pi * 100**2 * 10 / 3, rel=0.005)
    assert cone.area_m2[5] == pytest.approx(math.pi * 50**2, rel=0.005)
    assert cone.depth_m[-1] >= 10.0 - 1e-6 and cone.area_m2[-1] == 0.0


def test_contours_follow_the_plane_and_stop_at_empty_cells() -> None:
    c = np.arange(0.0, 100.0, 5.0) + 2.5
    gx, _gy = np.meshgrid(c, c)
    depth = 1.0 + gx / 20.0  # 1.125 m to 5.875 m, rising east
    depth[:, :4] = np.nan  # the west edge not mapped
    assert levels(depth, 1.0) == [3.0, 4.0, 5.0]  # 2 m lies in the empty cells
    found = contours(c, c, depth, 1.0)
    assert [f.level_m for f in found] == [3.0, 4.0, 5.0]
    for contour in found:
        for line in contour.lines:
            assert line[:, 0] == pytest.approx(20.0 * (contour.level_m - 1.0), abs=1e-9)


def test_a_line_sailed_half_way_is_not_bridged_to_by_the_hulls_sliver() -> None:
    """The last line stopped half-way: the convex hull still spans the water beyond its end,
    in long thin triangles from its last sounding; those cells are left empty, though a
    sounding of the line before is within the maximum distance."""
    x, y, _ = lines(count=4, length_m=400.0)
    half = (y == N0 + 60.0) & (x < E0 + 200.0)  # line 4 runs west and stops at 200 m
    x, y = x[~half], y[~half]
    spec = GridSpec.covering(x, y, 5.0)
    bent = 3.0 + 0.01 * (x - E0) ** 1.5 / 20.0  # no plane: a sliver would show
    grid, _ = make_grid(x, y, bent, spec, max_distance_m=15.0)
    gx, gy = np.meshgrid(spec.x, spec.y)
    beyond = (gy > N0 + 45.0) & (gx < E0 + 150.0)
    assert not grid.mapped[beyond].any()
    below = (gy > N0 + 21.0) & (gy < N0 + 39.0) & (gx > E0 + 5) & (gx < E0 + 395)
    assert grid.mapped[below].all()
    where_sailed = (np.abs(gy - (N0 + 50.0)) < 3.0) & (gx > E0 + 210) & (gx < E0 + 395)
    assert grid.mapped[where_sailed].all()


def test_a_single_line_has_no_contours() -> None:
    # The first line of a survey, gridded: one row of cells. contourpy refuses such a
    # grid; there is nothing to contour (it crashed `cc-daemon map` and the page).
    x = np.linspace(0.0, 60.0, 7)
    assert contours(x, np.array([0.0]), np.full((1, 7), 2.0) + x / 100, 0.1) == []
    assert contours(np.array([0.0]), x, np.full((7, 1), 2.0) + x[:, None] / 100, 0.1) == []


def test_too_few_held_out_blocks_estimate_nothing() -> None:
    x, y, _ = lines(count=2, length_m=30.0)
    blocks = block_median(x, y, plane(x, y), GridSpec.covering(x, y, 5.0))
    cv = block_kfold(blocks, block_m=10.0)
    assert cv.predicted < 20 and math.isnan(cv.rmse_m) and math.isnan(cv.bias_m)
