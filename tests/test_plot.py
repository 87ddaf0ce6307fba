"""Plots are real, non-empty PNGs; a missing matplotlib gives a clear message."""

from __future__ import annotations

import struct
import sys
import zlib
from pathlib import Path

import pytest

from cc_daemon.export import OptionalDependencyError
from cc_daemon.export.plot import plot_cast, plot_survey
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, write_survey

pytest.importorskip("matplotlib")

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def survey_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("survey") / "j.db"
    clock = FakeClock()
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    write_survey(journal, clock, duration_s=1800, cast_every_s=600)
    journal.close()
    return db


def check_png(path: Path, *, min_size: tuple[int, int]) -> tuple[int, int]:
    """Walk the PNG's chunks (CRCs included); return its width and height."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > 10_000  # a real figure, not an empty canvas
    offset, chunks = 8, []
    while offset < len(data):
        (length,) = struct.unpack(">I", data[offset : offset + 4])
        kind = data[offset + 4 : offset + 8]
        body = data[offset + 8 : offset + 8 + length]
        (crc,) = struct.unpack(">I", data[offset + 8 + length : offset + 12 + length])
        assert zlib.crc32(kind + body) == crc, kind
        chunks.append(kind)
        offset += 12 + length
    assert chunks[0] == b"IHDR" and chunks[-1] == b"IEND" and b"IDAT" in chunks
    width, height = struct.unpack(">II", data[16:24])
    assert width >= min_size[0] and height >= min_size[1]
    return width, height


def test_cast_plot_is_a_png(survey_db: Path, tmp_path: Path) -> None:
    with JournalReader(survey_db) as reader:
        cast = reader.casts(cast_id=2)[0]
        samples = reader.samples(cast_id=2)
    path = tmp_path / "cast.png"
    plot_cast(cast, samples, path)
    assert check_png(path, min_size=(800, 450)) == (960, 540)


def test_survey_plot_is_a_png(survey_db: Path, tmp_path: Path) -> None:
    with JournalReader(survey_db) as reader:
        casts, fixes = reader.casts(), reader.fixes()
    path = tmp_path / "survey.png"
    plot_survey(casts, fixes, path)
    check_png(path, min_size=(1000, 600))


def test_nothing_to_plot_is_an_error_not_an_empty_picture(survey_db: Path, tmp_path: Path) -> None:
    with JournalReader(survey_db) as reader:
        skipped = reader.casts(cast_id=1)[0]
    assert skipped.outcome == "skipped-shallow"
    with pytest.raises(ValueError, match="no depth samples"):
        plot_cast(skipped, [], tmp_path / "cast.png")
    with pytest.raises(ValueError, match="no track and no cast"):
        plot_survey([], [], tmp_path / "survey.png")
    assert not list(tmp_path.iterdir())


def test_missing_matplotlib_says_which_extra_to_install(
    survey_db: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with JournalReader(survey_db) as reader:
        casts, fixes = reader.casts(), reader.fixes()
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(OptionalDependencyError, match=r"-m pip install 'matplotlib>=3.8'"):
        plot_survey(casts, fixes, tmp_path / "survey.png")


def test_the_extension_says_the_format_and_others_are_refused(
    survey_db: Path, tmp_path: Path
) -> None:
    with JournalReader(survey_db) as reader:
        cast, samples = reader.casts(cast_id=2)[0], reader.samples(cast_id=2)
        casts, fixes = reader.casts(), reader.fixes()
    magic = {".png": PNG_SIGNATURE, ".pdf": b"%PDF-", ".svg": b"<?xml"}
    for suffix, start in magic.items():
        for name, draw in (
            ("cast", lambda p: plot_cast(cast, samples, p)),
            ("survey", lambda p: plot_survey(casts, fixes, p)),
        ):
            path = tmp_path / f"{name}{suffix.upper() if name == 'cast' else suffix}"
            draw(path)
            assert path.read_bytes().startswith(start), path
    for bad in ("x.jpg", "x", "x.png.txt"):
        with pytest.raises(ValueError, match=r"one of \.png, \.pdf, \.svg"):
            plot_cast(cast, samples, tmp_path / bad)
        with pytest.raises(ValueError, match=r"one of \.png, \.pdf, \.svg"):
            plot_survey(casts, fixes, tmp_path / bad)
        assert not (tmp_path / bad).exists()


def test_the_cast_legend_hides_no_data(survey_db: Path) -> None:
    from cc_daemon.export.plot import cast_figure

    with JournalReader(survey_db) as reader:
        figure = cast_figure(reader.casts(cast_id=2)[0], reader.samples(cast_id=2))
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(figure).get_renderer()
    figure.draw(renderer)
    [axes] = figure.axes
    [legend] = figure.legends
    assert not legend.get_window_extent(renderer).overlaps(axes.get_window_extent(renderer))


def test_each_station_outcome_looks_and_reads_differently(survey_db: Path) -> None:
    from cc_daemon.export.plot import _STATIONS, _station_label
    from cc_daemon.store.journal import OUTCOMES

    assert set(_STATIONS) == {*OUTCOMES, "running"}
    looks = {
        (style.get("marker"), style.get("color"), style.get("facecolors"))
        for _, style in _STATIONS.values()
    }
    assert len(looks) == len(_STATIONS)
    with JournalReader(survey_db) as reader:
        skipped, measured = reader.casts(cast_id=1)[0], reader.casts(cast_id=2)[0]
    assert _station_label(skipped) == "#1 skipped"
    assert _station_label(measured) == f"#2 {measured.reached_depth_m:.2f} m"
    assert _station_label(measured._replace(outcome="aborted", reached_depth_m=1.0)) == (
        "#2 aborted at 1.00 m"
    )
    assert _station_label(measured._replace(outcome=None, reached_depth_m=None)) == "#2 running"


def test_a_sentinel_sonar_distance_is_no_bottom_on_the_plot(survey_db: Path) -> None:
    from cc_daemon.export.plot import _sounded, cast_figure

    with JournalReader(survey_db) as reader:
        cast, samples = reader.casts(cast_id=2)[0], reader.samples(cast_id=2)
    # A blind cast's M frame: 4294967295 mm at 100 % (issue 19) is no bottom to draw.
    blind = cast._replace(water_depth_m=4294967.295, sonar_confidence_pct=100)
    [axes] = cast_figure(blind, samples).axes
    assert axes.get_ylim()[0] < 100  # not scaled to 4,295 km of water
    assert not any("bottom" in str(line.get_label()) for line in axes.get_lines())
    assert _sounded(8.219, 90) and not _sounded(0.0, 100) and not _sounded(8.2, 0)
