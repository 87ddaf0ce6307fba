"""The profiles' figures, checked as images: what is drawn where, read back from the PNG."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cc_daemon.export.profiles.castplot import DPI, MARK, cast_figure, plot_cast
from cc_daemon.export.profiles.sections import BED, plot_section, section_figure, stations
from cc_daemon.export.profiles.survey import Survey, profile_survey
from cc_daemon.sim.water import WaterColumn
from cc_daemon.store import JournalReader
from tests.profilekit import CastSpec, write_journal

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def survey(tmp_path_factory: pytest.TempPathFactory) -> Survey:
    db = tmp_path_factory.mktemp("plots") / "j.db"
    write_journal(
        db,
        [
            CastSpec(WaterColumn(), seed=1, north_m=0.0, sonar_m=7.0),
            CastSpec(WaterColumn(thermocline_m=3.0), seed=2, north_m=200.0, sonar_m=5.5),
            CastSpec(WaterColumn(thermocline_m=2.5), seed=3, north_m=400.0, sonar_m=9.0),
        ],
    )
    with JournalReader(db) as reader:
        return profile_survey(reader.casts(), reader.sonde_samples(), reader.events())


def rgb(colour: str) -> np.ndarray:
    from matplotlib.colors import to_rgb

    return np.array(to_rgb(colour))


def pixel(image: np.ndarray, fig: Any, ax: Any, x: float, y: float) -> np.ndarray:
    """The colour the PNG of `fig` has at data point (x, y) of `ax`."""
    px, py = ax.transData.transform((x, y)) * (DPI / fig.dpi)
    return np.asarray(image[round(image.shape[0] - py), round(px), :3])


def saved(fig: Any, path: Path) -> np.ndarray:
    import matplotlib.image

    fig.savefig(str(path), dpi=DPI)
    image = matplotlib.image.imread(str(path))
    assert image.shape[0] > 400 and image.shape[1] > 600
    assert np.ptp(image[..., :3]) > 0.5  # something drawn, not a blank canvas
    return np.asarray(image)


def test_a_cast_plot_marks_the_thermocline_over_binned_and_raw_ways(
    survey: Survey, tmp_path: Path
) -> None:
    cast = survey.casts[0]
    fig = cast_figure(survey, cast)
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in panels] == [c.name for c in survey.columns]
    temperature = panels[0]
    assert temperature.get_xlabel() == "water temperature [degC]"
    assert temperature.get_ylabel() == "depth [m]"
    low, high = temperature.get_ylim()
    assert low > high  # depth increasing downwards
    labels = [text.get_text() for text in fig.legends[0].get_texts()]
    thermocline = cast.reading.numbers["thermocline_m"]
    assert thermocline is not None
    assert labels == [
        "down, as read", "up, as read", "soak, dwell, turns", "down, binned", "up, binned",
        "metalimnion top, bottom", f"thermocline {thermocline:.2f} m",
    ]  # fmt: skip
    assert "SIMULATED" in fig._suptitle.get_text()
    image = saved(fig, tmp_path / "cast.png")
    x0, x1 = temperature.get_xlim()
    # The thermocline is a red line across the panel, where the numbers say.
    left = pixel(image, fig, temperature, x0 + 0.03 * (x1 - x0), thermocline)
    assert np.abs(left - rgb(MARK)).max() < 0.25
    plot_cast(survey, cast, tmp_path / "written.png")
    assert (tmp_path / "written.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_section_is_contoured_and_masked_below_the_bed(survey: Survey, tmp_path: Path) -> None:
    column = survey.columns[0]
    fig = section_figure(survey, column)
    ax = fig.axes[0]
    assert ax.get_xlabel().startswith("distance along the survey [m]")
    assert ax.get_ylim()[0] > ax.get_ylim()[1]
    colorbar = fig.axes[1]
    assert colorbar.get_ylabel() == "water temperature [degC]"
    image = saved(fig, tmp_path / "section.png")
    # Beside the second station (bed 5.5 m; its tick is white): brown at 6 m, the water's
    # colours at 3 m.
    second = stations(survey)[1][0] + 5.0
    below = pixel(image, fig, ax, second, 6.0)
    above = pixel(image, fig, ax, second, 3.0)
    assert np.abs(below - rgb(BED)).max() < 0.05
    assert np.abs(above - rgb(BED)).max() > 0.2
    plot_section(survey, column, tmp_path / "written.png")
    assert (tmp_path / "written.png").read_bytes()[:4] == b"\x89PNG"


def test_casts_planned_to_resolve_no_lag_are_not_lag_corrected(tmp_path: Path) -> None:
    # The simulator's fast pace plans `profile.resolve = []`: readings 1.25 m apart,
    # from which an inverse correction drew water warmer than any in the lake.
    for resolve, expected in (([], "none"), (["temperature"], "inverse"), (None, "inverse")):
        db = tmp_path / f"{resolve}.db"
        write_journal(db, [CastSpec(seed=1, resolve=resolve), CastSpec(seed=2, resolve=resolve)])
        with JournalReader(db) as reader:
            made = profile_survey(reader.casts(), reader.sonde_samples(), reader.events())
            asked = profile_survey(
                reader.casts(), reader.sonde_samples(), reader.events(), method="inverse"
            )
        assert made.settings.method == expected, resolve
        assert any("not corrected" in n for n in made.notes) == (expected == "none")
        assert asked.settings.method == "inverse"  # asked for: done
