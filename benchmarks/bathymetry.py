"""Issue 30's goals: the lake floor against the simulator's true bed, and a day in seconds.

A twelve-hour lines survey (64 lines of 1,000 m, 20 m apart, at 1.5 m/s: 86,400
fixes with the autopilot's sonar and 172,800 readings of the companion
computer's Ping1D, both with 3 % outliers, 5 % dropouts, heave and a GPS glitch
in a thousand fixes) is written straight from the simulator's models into a
journal (`sim.bathysurvey`). Then:

- accuracy: the grid `cc-daemon map` makes, against the true bed at each mapped
  cell's centre: RMSE <= 0.10 m and |bias| <= 0.03 m; the cross-validated RMSE
  the product reports within a factor of 1.5 of that true RMSE;
- hypsography, over the mapped cells: the volume within 2 % of the true bed's,
  and the area at every depth within 1 % (of the area mapped) of the true bed's
  (4 x 4 samples of the true bed in each cell);
- quality control: at least 95 % of the injected outliers (second echoes and
  shallow returns) rejected, at most 2 % of the good soundings;
- scale: `cc-daemon map` on that journal, every product written, as a child
  process: wall time <= 15 s and peak resident memory <= 500 MB; and the same
  under a 10 % CPU quota (`benchmarks.goals.CpuQuota`, a cgroup), as the Pi-class
  figure (no goal: a figure).

    python -m benchmarks.bathymetry      (or: make bench)
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.goals import CpuQuota
from cc_daemon.config.survey import SurveySettings
from cc_daemon.export.bathymap import MapOptions, make_map
from cc_daemon.science.hypsography import Hypsography
from cc_daemon.sim.bathysurvey import SurveyTruth, write_lines_survey
from cc_daemon.sim.echosounder import EchoErrors
from cc_daemon.sim.lines import make_lines_mission
from cc_daemon.sim.mission import from_lat_lon
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock

HOURS = float(os.environ.get("BENCH_BATHY_HOURS", "12"))
LINES, LINE_M, SPACING_M = 64, 1000.0, 20.0
ERRORS = EchoErrors(outlier_rate=0.03, dropout_rate=0.05)
DRAFTS = {"autopilot_draft_m": 0.10, "onboard_draft_m": 0.15}
GOAL_S, GOAL_MB = 15.0, 500.0
# BENCH_BATHY_COMPARE=1: also each interpolator's figures (docs/maps.md's choice), minutes more.
COMPARE = os.environ.get("BENCH_BATHY_COMPARE") == "1"


def write_day(db: Path) -> SurveyTruth:
    clock = FakeClock()
    journal = Journal(
        db, monotonic=clock.monotonic, wall=clock.wall, winch_backend="sim", simulated=True
    )
    journal.open()
    try:
        mission = make_lines_mission(3, 1, spacing_m=SPACING_M, lines=LINES, line_length_m=LINE_M)
        return write_lines_survey(
            journal, clock, mission, duration_s=HOURS * 3600, errors=ERRORS, glitch_rate=0.001,
            **DRAFTS,
        )  # fmt: skip
    finally:
        journal.close()


def true_bed(truth: SurveyTruth, crs: Any, x: Any, y: Any) -> Any:
    from pyproj import Transformer

    back = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = back.transform(x, y)
    east, north = from_lat_lon(np.asarray(lat), np.asarray(lon))
    return truth.mission.field.depth_xy(east, north, np)


def timed_map(db: Path, out: Path, quota: CpuQuota | None = None) -> tuple[float, float, float]:
    """`cc-daemon map` as a child process: wall s, CPU s, peak resident MB."""
    command = [sys.executable, "-m", "cc_daemon", "map", "--db", str(db), "-o", str(out)]
    began = time.monotonic()
    proc = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        preexec_fn=quota.enter if quota is not None else None,  # noqa: PLW1509
    )
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.monotonic() - began
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode() if proc.stderr else ""
    if proc.stderr:
        proc.stderr.close()
    if proc.returncode != 0:
        raise RuntimeError(f"cc-daemon map failed ({proc.returncode}): {err}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0


def line(goal: str, figure: str, passed: bool | None) -> bool:
    word = "SKIP" if passed is None else "PASS" if passed else "FAIL"
    print(f"  {word}  {goal}: {figure}", flush=True)
    return passed is not False


def main() -> int:
    ok = True
    with tempfile.TemporaryDirectory(prefix="cc-daemon-bench-bathy-") as tmp:
        db = Path(tmp) / "day.db"
        began = time.monotonic()
        truth = write_day(db)
        print(
            f"  a {HOURS:g}-hour lines survey: {truth.fixes} fixes and {truth.pings} Ping1D"
            f" readings written in {time.monotonic() - began:.1f} s"
            f" ({db.stat().st_size / 1e6:.0f} MB journal)",
            flush=True,
        )
        with JournalReader(db) as reader:
            survey = reader.select_survey("latest")
            assert survey is not None
            made = make_map(reader, survey, MapOptions(survey=SurveySettings(**DRAFTS)))
        bed, grid = made.bed, made.bed.grid
        gx, gy = np.meshgrid(grid.spec.x, grid.spec.y)
        mapped = grid.mapped
        error = (grid.depth_m - true_bed(truth, made.soundings.crs, gx, gy))[mapped]
        rmse, bias = float(np.sqrt(np.mean(error**2))), float(error.mean())
        print(
            f"  grid: {bed.cell_m:g} m cells ({grid.spec.nx} x {grid.spec.ny}), {bed.method},"
            f" line spacing found {bed.spacing_m:.2f} m, {grid.mapped_cells} cells mapped;"
            f" largest error {np.abs(error).max():.3f} m"
        )
        ok &= line("true RMSE <= 0.10 m", f"{rmse:.4f} m", rmse <= 0.10)
        ok &= line("|true bias| <= 0.03 m", f"{bias:+.4f} m", abs(bias) <= 0.03)
        ratio = bed.cv.rmse_m / rmse
        ok &= line(
            "reported CV RMSE within x1.5 of the true RMSE",
            f"{bed.cv.rmse_m:.4f} m reported (raw {bed.cv.raw_rmse_m:.4f} m), x{ratio:.2f}",
            1 / 1.5 <= ratio <= 1.5,
        )
        ok &= hypsography_goals(made, truth, gx, gy)
        ok &= qc_goals(made, truth)
        ok &= scale_goals(db, Path(tmp))
        if COMPARE:
            compare(made, truth)
    return 0 if ok else 1


def compare(made: Any, truth: SurveyTruth) -> None:
    """Each interpolator on the same block medians: its true RMSE, its reported CV RMSE
    and the time to grid and to cross-validate (figures, no goal)."""
    from cc_daemon.science.bathymetry import interpolate
    from cc_daemon.science.bathymetry.grid import make_grid, max_edge_m
    from cc_daemon.science.bathymetry.spacing import cv_block_m
    from cc_daemon.science.bathymetry.validation import block_kfold

    kept = made.soundings.kept
    x, y, z = (a[kept] for a in (made.soundings.x_m, made.soundings.y_m, made.soundings.depth_m))
    spec, reach = made.bed.grid.spec, made.bed.max_distance_m
    gx, gy = np.meshgrid(spec.x, spec.y)
    bed = true_bed(truth, made.soundings.crs, gx, gy)
    for method in interpolate.METHODS:
        began = time.process_time()
        grid, blocks = make_grid(x, y, z, spec, max_distance_m=reach, method=method)
        gridded = time.process_time() - began
        began = time.process_time()
        cv = block_kfold(blocks, block_m=cv_block_m(made.bed.rules_spacing_m), method=method,
                         max_edge_m=max_edge_m(reach))  # fmt: skip
        validated = time.process_time() - began
        error = (grid.depth_m - bed)[grid.mapped]
        rmse = float(np.sqrt(np.mean(error**2)))
        print(
            f"  ----  {method:<10} true RMSE {rmse:.4f} m, bias {error.mean():+.4f} m,"
            f" largest {np.abs(error).max():.3f} m; CV RMSE {cv.rmse_m:.4f} m"
            f" (x{cv.rmse_m / rmse:.2f}); CPU {gridded:.1f} s to grid, {validated:.1f} s to"
            " cross-validate",
            flush=True,
        )


def hypsography_goals(made: Any, truth: SurveyTruth, gx: Any, gy: Any) -> bool:
    grid, hyps = made.bed.grid, made.bed.hypsography
    cell = grid.spec.cell_m
    offsets = (np.arange(4) + 0.5) / 4 - 0.5
    samples = []
    for dx in offsets:
        for dy in offsets:
            bed = true_bed(truth, made.soundings.crs, gx + dx * cell, gy + dy * cell)
            samples.append(np.where(grid.mapped, bed, np.nan))
    fine = np.stack(samples)
    interval = float(hyps.depth_m[1] - hyps.depth_m[0])
    true = Hypsography.from_depths(fine, cell * cell / 16.0, interval)
    volume = abs(hyps.volume_m3[0] - true.volume_m3[0]) / true.volume_m3[0]
    n = min(len(hyps.depth_m), len(true.depth_m))
    area = float(np.max(np.abs(hyps.area_m2[:n] - true.area_m2[:n]))) / true.area_m2[0]
    ok = line(
        "volume within 2 %",
        f"{hyps.volume_m3[0]:,.0f} m³ against {true.volume_m3[0]:,.0f} m³ ({volume:.3%})",
        volume <= 0.02,
    )
    return ok & line(
        "area at every depth within 1 % (of the mapped area)",
        f"worst {area:.3%} over {n} depths every {interval:g} m;"
        f" mapped {hyps.area_m2[0] / 1e6:.3f} km²",
        area <= 0.01,
    )


def qc_goals(made: Any, truth: SurveyTruth) -> bool:
    kinds = np.array([k.value for k in truth.fix_kinds + truth.ping_kinds])
    rejected = ~made.soundings.kept
    outlier = np.isin(kinds, ["second echo", "shallow return"])
    good = kinds == "good"
    caught = float(rejected[outlier].mean())
    lost = float(rejected[good].mean())
    ok = line(
        ">= 95 % of injected outliers rejected",
        f"{caught:.2%} of {int(outlier.sum())}",
        caught >= 0.95,
    )
    counts = ", ".join(f"{n} {why}" for why, n in made.soundings.counts().items())
    print(f"        reasons: {counts}")
    return ok & line(
        "<= 2 % of good soundings rejected", f"{lost:.2%} of {int(good.sum())}", lost <= 0.02
    )


def scale_goals(db: Path, tmp: Path) -> bool:
    wall, cpu, peak = timed_map(db, tmp / "products")
    load = os.getloadavg()[0]
    ok = line(
        f"a {HOURS:g}-hour day mapped (every product) in <= {GOAL_S:g} s",
        f"{wall:.1f} s wall, {cpu:.1f} s CPU (load average {load:.1f})",
        wall <= GOAL_S,
    )
    ok &= line(f"... in <= {GOAL_MB:g} MB", f"{peak:.0f} MB peak resident", peak <= GOAL_MB)
    quota = CpuQuota(0.10)
    if quota.path is None:
        line("under a 10 % CPU quota (Pi-class)", quota.why_not, None)
        return ok
    try:
        wall, cpu, peak = timed_map(db, tmp / "products-quota", quota)
    finally:
        quota.close()
    print(
        f"  ----  under a 10 % CPU quota (the Pi-class figure, no goal): {wall:.1f} s wall,"
        f" {cpu:.1f} s CPU, {peak:.0f} MB",
        flush=True,
    )
    return ok


if __name__ == "__main__":
    raise SystemExit(main())
