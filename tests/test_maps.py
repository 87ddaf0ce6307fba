"""Maps a scientist would publish: a metre is a metre both ways, no label is clipped
or covers another text, and no axis hides its numbers behind an offset."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.config.sonde import DEFAULT_PARAMETERS
from cc_daemon.export.mapframe import LocalFrame, fixed_texts
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, write_survey

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def survey_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("maps") / "j.db"
    clock = FakeClock()
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    # Casts every 2 minutes: stations tens of metres apart, labels that could collide.
    write_survey(journal, clock, duration_s=1800, cast_every_s=120)
    journal.close()
    return db


def drawn(fig: Any) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    return renderer


def check_readable(fig: Any, labels: list[str]) -> None:
    renderer = drawn(fig)
    [ax] = [a for a in fig.axes if a.get_label() != "<colorbar>"]
    # Equal aspect: the same number of pixels per metre on both axes.
    box = ax.get_window_extent(renderer)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert box.width / (x1 - x0) == pytest.approx(box.height / (y1 - y0), rel=1e-3)
    # Plain numbers: no "+4.045e1" beside an axis.
    assert ax.xaxis.get_offset_text().get_text() == ""
    assert ax.yaxis.get_offset_text().get_text() == ""
    # Every point label is there, inside the axes and the figure, over no other text.
    annotations = [t for t in ax.texts if t.get_text()]
    assert sorted(t.get_text() for t in annotations) == sorted(labels)
    figure_box = fig.bbox
    others = [t for t in fixed_texts(fig) if t.get_text() and t.get_visible()]
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in annotations]
    for i, (text, bb) in enumerate(boxes):
        assert box.contains(bb.x0, bb.y0) and box.contains(bb.x1, bb.y1), text
        assert figure_box.contains(bb.x0, bb.y0) and figure_box.contains(bb.x1, bb.y1), text
        for other_text, other in boxes[i + 1 :]:
            assert not bb.overlaps(other), (text, other_text)
        for other in others:
            assert not bb.overlaps(other.get_window_extent(renderer)), (text, other.get_text())


def test_the_survey_map_is_metric_and_its_labels_are_readable(survey_db: Path) -> None:
    from cc_daemon.export.plot import _station_label, survey_figure
    from cc_daemon.store.stations import names

    with JournalReader(survey_db) as reader:
        casts, fixes, stations = reader.casts(), reader.fixes(), reader.stations()
    assert len(casts) >= 10
    fig = survey_figure(casts, fixes, stations)
    named = names(stations)
    check_readable(fig, [_station_label(c, named[c.id]) for c in casts])
    [ax] = [a for a in fig.axes if a.get_label() != "<colorbar>"]
    assert ax.get_xlabel().startswith("metres east of ")


def test_the_sonde_map_is_metric_and_its_labels_are_readable(survey_db: Path) -> None:
    from cc_daemon.export.sonde import Column
    from cc_daemon.export.sondeplot import map_figure
    from cc_daemon.store.sonde import SondeSampleRecord

    with JournalReader(survey_db) as reader:
        casts = reader.casts()
    samples = [
        SondeSampleRecord(
            c.id,
            "descending",
            0.0,
            0.0,
            True,
            0.1,
            "ok",
            None,
            2.0,
            2.0,
            False,
            {"temperature": 20.0 + c.id / 10},
            {},
        )
        for c in casts
    ]
    columns = [Column(p.name, p.unit, p.name, None) for p in DEFAULT_PARAMETERS]
    fig, count = map_figure(casts, samples, columns, "temperature", 2.0)
    assert count == len(casts)
    check_readable(fig, [str(c.id) for c in casts])


def test_the_local_frame_measures_metres() -> None:
    frame = LocalFrame.around([40.45, 40.46], [-3.72, -3.71])
    # 0.01 degree of latitude is 1112 m; of longitude at 40.455 N, 846 m.
    assert frame.north_m(40.46) == pytest.approx(1111.9, abs=0.2)
    assert frame.east_m(-3.71) == pytest.approx(1111.9 * math.cos(math.radians(40.455)), abs=0.2)
    assert frame.origin_text() == "40.45000°N 3.72000°W"
