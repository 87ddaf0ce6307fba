"""The frame every map of the survey is drawn in, and where its labels go.

It owns what every plot shares: a matplotlib figure (imported only when
drawing; a missing one raises `OptionalDependencyError`), a local metric frame
(metres east and north of the survey's south-west corner, equal aspect: a metre
is a metre both ways, which degrees are not), the placement of point labels so
that no label covers another label, a tick label or the axes' titles, and none
is clipped, and `shown`: text from the journal as a plot may draw it (a
stranger's journal may hold a phase of a megabyte, which matplotlib would lay
out for minutes and gigabytes, or `$...$`, which it would parse as mathematics).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from cc_daemon.export import OptionalDependencyError

EARTH_RADIUS_M = 6_371_008.8  # the mean radius (IUGG): metres per radian
# Where a label may sit around its point, in points, tried in this order.
_OFFSETS = [(6, 4), (6, -12), (-6, 4), (-6, -12), (0, 10), (0, -16), (12, -4), (-12, -4)]
_FARTHER = [(dx * 2, dy * 2) for dx, dy in _OFFSETS]
_MARKER_PT = 5.0  # half a station marker's width (s=70 points squared), in points


LABEL_CHARS = 80  # the shipped sonde map's longest name is 43: "phycocyanin (blue-green ...)"


def shown(text: object, limit: int = LABEL_CHARS) -> str:
    """Text from the journal as a label: printable, at most `limit` characters (an
    ellipsis where it was cut), every `$` drawn as a dollar, not as mathematics."""
    plain = "".join(c if c.isprintable() else " " for c in str(text)[: limit + 1])
    if len(plain) > limit:
        plain = plain[: limit - 1] + "\u2026"
    return plain.replace("$", r"\$")


def figure(width_in: float, height_in: float) -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise OptionalDependencyError("plotting", "matplotlib", "plot") from exc
    return Figure(figsize=(width_in, height_in), layout="constrained")


@dataclass(frozen=True, slots=True)
class LocalFrame:
    """Metres east and north of (lat0, lon0): equirectangular about the survey's
    mean latitude; over a survey of a few kilometres it is exact to centimetres."""

    lat0: float
    lon0: float
    cos_lat: float

    @classmethod
    def around(cls, lats: Sequence[float], lons: Sequence[float]) -> LocalFrame:
        mean = sum(lats) / len(lats)
        return cls(min(lats), min(lons), max(math.cos(math.radians(mean)), 1e-6))

    def east_m(self, lon: float) -> float:
        return math.radians(lon - self.lon0) * EARTH_RADIUS_M * self.cos_lat

    def north_m(self, lat: float) -> float:
        return math.radians(lat - self.lat0) * EARTH_RADIUS_M

    def xy(self, lats: Sequence[float], lons: Sequence[float]) -> tuple[list[float], list[float]]:
        return [self.east_m(lon) for lon in lons], [self.north_m(lat) for lat in lats]

    def origin_text(self) -> str:
        ns = "N" if self.lat0 >= 0 else "S"
        ew = "E" if self.lon0 >= 0 else "W"
        return f"{abs(self.lat0):.5f}°{ns} {abs(self.lon0):.5f}°{ew}"


def metric_axes(ax: Any, frame: LocalFrame) -> None:
    """Equal aspect, plain metre ticks (no offset, no scientific notation), room for labels."""
    from matplotlib.ticker import MaxNLocator

    ax.set_aspect("equal", adjustable="datalim")
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.yaxis.set_major_locator(MaxNLocator(6))
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.margins(0.12)
    ax.set_xlabel(f"metres east of {frame.origin_text()}")
    ax.set_ylabel("metres north")


def place_labels(
    fig: Any,
    ax: Any,
    points: Sequence[tuple[float, float]],
    texts: Sequence[str],
    *,
    markers: bool = False,
    **style: Any,
) -> list[Any]:
    """Annotate each point, choosing for each label the first place around its point
    that overlaps nothing already drawn (labels, ticks, titles, and with `markers`
    the points' own markers) and stays inside the axes; where no place is free, the
    one that overlaps least. The axes grow to fit the labels if need be."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.transforms import Bbox

    renderer = FigureCanvasAgg(fig).get_renderer()  # type: ignore[no-untyped-call]
    fig.draw(renderer)  # lays out the ticks and titles the labels must avoid
    taken = [t.get_window_extent(renderer) for t in fixed_texts(fig) if t.get_text()]
    if markers:  # a station's marker is as much to be seen as a label
        half = _MARKER_PT * fig.dpi / 72
        for x, y in points:
            px, py = ax.transData.transform((x, y))
            taken.append(Bbox.from_extents(px - half, py - half, px + half, py + half))
    placed = []
    inside = ax.get_window_extent(renderer)

    def put(text: str, x: float, y: float, dx: int, dy: int) -> tuple[Any, float | None]:
        """The label at (dx, dy) points from its point, and how much it covers (None:
        not inside the axes)."""
        # Left of the point the text ends there; above or below it is centred.
        align = "left" if dx > 0 else "right" if dx < 0 else "center"
        label = ax.annotate(
            text, (x, y), xytext=(dx, dy), textcoords="offset points", ha=align, zorder=4,
            **style,
        )  # fmt: skip
        box = label.get_window_extent(renderer)
        if not (inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1)):
            return label, None
        return label, sum(_overlap(box, other) for other in taken)

    for (x, y), text in zip(points, texts, strict=True):
        best: tuple[float, int, int] | None = None  # the least covering place, if none is free
        for dx, dy in _OFFSETS + _FARTHER:
            label, covered = put(text, x, y, dx, dy)
            if covered == 0:
                break
            if covered is not None and (best is None or covered < best[0]):
                best = (covered, dx, dy)
            label.remove()
        else:
            label, _ = put(text, x, y, *(best[1:] if best else _FARTHER[-1]))
        taken.append(label.get_window_extent(renderer))
        placed.append(label)
    return placed


def _overlap(a: Any, b: Any) -> float:
    """The area two boxes share, in square pixels."""
    width = min(a.x1, b.x1) - max(a.x0, b.x0)
    height = min(a.y1, b.y1) - max(a.y0, b.y0)
    return float(max(width, 0.0) * max(height, 0.0))


def fixed_texts(fig: Any) -> list[Any]:
    """Every text of the figure that is not a point label: titles, axis and tick labels."""
    out = list(fig.texts)
    for ax in fig.axes:
        out += [ax.title, ax._left_title, ax._right_title, ax.xaxis.label, ax.yaxis.label]
        out += ax.get_xticklabels() + ax.get_yticklabels()
        out += [ax.xaxis.get_offset_text(), ax.yaxis.get_offset_text()]
    return out
