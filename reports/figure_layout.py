"""Fixed layouts of the report's figures: a grid of axes (and colorbars) placed once, from their text.

matplotlib's constrained layout finds the margins of a grid of axes by measuring every decoration of
every axes (ticks made as artists, each label laid out) twice, and the draw measures them all again to
place each axis label: for a report figure that was more than half of its CPU time. The margins depend
only on a few strings: the tick labels (from each axis' locator and formatter, as the draw makes them),
the axis labels and the titles. :func:`lay_out` measures those strings' extents as the SVG draws them
(on svg_backend.py's renderer at 72 dpi, whose text cache the draw then finds filled), places the
axes, their colorbars and the figure's title with the room the constrained layout would leave (``PAD``
around every decorated axes; rows of equal height, columns of equal width), and pins each axis label
where the draw would have put it, so that the draw does not search for it again.

What it measures: the tick labels of both sides of each axis (major and minor, unrotated), the offset
text, the axis labels, the centre title and tick labels overhanging the axes' ends; legends and texts
inside the axes need no room. A figure laid out here has no layout engine: ``savefig`` draws it once.

:func:`pin_ticks` (document.py ``svg_uri``, before every report figure is saved) keeps only the ticks the
draw shows: a tick locator gives a step's worth of ticks beyond each end of the view, and the draw
makes a whole tick (two lines, a grid line, two labels: ~1 ms each) for every location before it drops
those outside: about a third of the ticks a report made.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # typed by name only
    from matplotlib.axes import Axes
    from matplotlib.axis import Axis
    from matplotlib.backend_bases import RendererBase
    from matplotlib.cm import ScalarMappable
    from matplotlib.colorbar import Colorbar
    from matplotlib.figure import Figure
    from matplotlib.font_manager import FontProperties
    from matplotlib.text import Text

PAD = 3 / 72  # [in] around each axes with its decorations (constrained layout's w_pad and h_pad)
BAR_PAD = 0.05  # a colorbar's gap to its axes, in widths of that axes (matplotlib's default)
OFFSET_PAD = 3 / 72  # [in] an axis' offset text ("1e4") from its tick labels (matplotlib's)


@dataclass(frozen=True)
class Bar:
    """A vertical colorbar right of grid column ``col`` over the rows ``rows``; its width is its
    height over ``aspect`` (matplotlib's default 20 for a colorbar beside one axes)."""

    mappable: ScalarMappable
    col: int
    rows: slice
    label: str = ""
    aspect: float = 20.0


@dataclass(frozen=True)
class Room:
    """Inches an axes' decorations take beyond each of its sides, and where its axis labels go:
    ``ylabel`` from the edge the label is on, ``xlabel`` from the bottom edge (None: no label)."""

    left: float
    right: float
    bottom: float
    top: float
    ylabel: float | None
    xlabel: float | None


def _shown_ticks(axis: Axis, which: str) -> list[tuple[float, str]]:
    """(value, label) of the ticks the draw labels on ``axis``: in the view, non-empty, as its
    locator and formatter give them (the minor ones that fall on major ones dropped, as the draw does)."""
    from matplotlib.ticker import NullFormatter

    ticker = axis.major if which == "major" else axis.minor
    if isinstance(ticker.formatter, NullFormatter):
        return []
    locs = np.asarray(ticker.locator(), float)
    if which == "minor" and locs.size:
        major = np.asarray(axis.major.locator(), float)
        if major.size:
            locs = locs[~np.isclose(locs[:, None], major[None, :], rtol=1e-10, atol=0).any(axis=1)]
    labels = ticker.formatter.format_ticks(list(locs))
    lo, hi = sorted(axis.get_view_interval())
    tol = 1e-10 * (hi - lo)
    return [(v, s) for v, s in zip(locs, labels, strict=True) if s and lo - tol <= v <= hi + tol]


@dataclass(frozen=True)
class _AxisRoom:
    side1: float  # [in] outside the left (y) or bottom (x) spine
    side2: float  # outside the right or top spine
    low: float  # [in] tick labels past the axis' low end (bottom or left)
    high: float  # past its high end
    offset: float  # [in] height of its offset text (0: none)


class _Metrics:
    """Text extents (width, height, descent) [px] on a renderer, each string measured once per layout;
    and the size of each text artist (an axis label, a title), laid out once per layout: its size does
    not change as the axes move."""

    def __init__(self, renderer: RendererBase) -> None:
        self.renderer = renderer
        self._seen: dict[tuple[str, FontProperties], tuple[float, float, float]] = {}
        self._sizes: dict[int, tuple[Text, float, float]] = {}

    def size(self, text: Text) -> tuple[float, float]:
        """(width, height) [px] of ``text`` as drawn (0 for none)."""
        if not text.get_visible() or not text.get_text():
            return 0.0, 0.0
        if (known := self._sizes.get(id(text))) is None or known[0] is not text:
            bb = text.get_window_extent(self.renderer)
            known = self._sizes[id(text)] = (text, bb.width, bb.height)
        return known[1], known[2]

    def __call__(self, s: str, prop: FontProperties) -> tuple[float, float, float]:
        from matplotlib import cbook

        key = (s, prop)
        if key not in self._seen:
            ismath = cbook.is_math_text(s)
            self._seen[key] = self.renderer.get_text_width_height_descent(s, prop, ismath=ismath)
        return self._seen[key]


def _axis_room(axis: Axis, metrics: _Metrics, along: float) -> _AxisRoom:
    """The room an axis' tick labels need; ``along`` [in] is the axis' length."""
    dpi = axis.axes.get_figure(root=True).dpi
    vertical = axis.axis_name == "y"
    shown = _shown_ticks(axis, "major") + _shown_ticks(axis, "minor")
    if not shown:  # e.g. a colorbar's short axis
        return _AxisRoom(0.0, 0.0, 0.0, 0.0, 0.0)
    tick = axis.majorTicks[0]  # made once: the draw reuses it
    on1, on2 = tick.label1.get_visible(), tick.label2.get_visible()
    if not (on1 or on2):
        return _AxisRoom(0.0, 0.0, 0.0, 0.0, 0.0)
    prop = tick.label1.get_fontproperties()
    _, h_lp, d_lp = metrics("lp", prop)
    to_frac = axis.axes.transScale + axis.axes.transLimits
    values = np.array([v for v, _ in shown], float)
    at = np.column_stack((np.zeros_like(values), values) if vertical else (values, np.zeros_like(values)))
    fracs = to_frac.transform(at)[:, 1 if vertical else 0]  # each tick's place along the axis, at once
    across = low = high = 0.0
    for (_, s), frac in zip(shown, fracs, strict=True):
        w, h, d = metrics(s, prop)
        h = max(h - d, h_lp - d_lp) + max(d, d_lp)  # a line's height as matplotlib's text layout has it
        across = max(across, (w if vertical else h) / dpi)
        half = (h if vertical else w) / dpi / 2  # a label is centred on its tick
        low = max(low, half - frac * along)
        high = max(high, half - (1 - frac) * along)
    extent = (tick.get_pad() + tick.get_tick_padding()) / 72 + across if across else 0.0
    offset = 0.0
    if text := axis.major.formatter.get_offset():
        offset = OFFSET_PAD + metrics(text, axis.offsetText.get_fontproperties())[1] / dpi
    return _AxisRoom(extent if on1 else 0.0, extent if on2 else 0.0, low, high, offset)


def room(ax: Axes, metrics: _Metrics, size: tuple[float, float]) -> Room:
    """What ``ax`` needs around it, the axes being ``size`` [in] (width, height)."""
    from matplotlib import rcParams

    dpi = ax.get_figure(root=True).dpi
    y = _axis_room(ax.yaxis, metrics, size[1])
    x = _axis_room(ax.xaxis, metrics, size[0])
    left, right = max(y.side1, x.low), max(y.side2, x.high)
    bottom, top = max(x.side1 + x.offset, y.low), max(x.side2, y.high, y.offset)

    def extent(text: Text) -> tuple[float, float]:
        w, h = metrics.size(text)
        return w / dpi, h / dpi

    ylabel = xlabel = None
    if w := extent(ax.yaxis.label)[0]:
        if ax.yaxis.get_label_position() == "left":
            ylabel = y.side1 + ax.yaxis.labelpad / 72
            left = max(left, ylabel + w)
        else:
            ylabel = y.side2 + ax.yaxis.labelpad / 72
            right = max(right, ylabel + w)
    if h := extent(ax.xaxis.label)[1]:
        xlabel = x.side1 + ax.xaxis.labelpad / 72
        bottom = max(bottom, xlabel + h)
    if h := extent(ax.title)[1]:  # at the axes' top plus the title pad (document.py STYLE)
        top = max(top, float(rcParams["axes.titlepad"]) / 72 + h)
    return Room(left, right, bottom, top, ylabel, xlabel)


def _pin_labels(ax: Axes, r: Room, size: tuple[float, float]) -> None:
    """Put the axis labels where the draw would (``Room``), in axes coordinates: fixed, so that the
    draw does not measure every tick label again to place them."""
    if r.ylabel is not None:
        x = -r.ylabel / size[0] if ax.yaxis.get_label_position() == "left" else 1 + r.ylabel / size[0]
        ax.yaxis.set_label_coords(x, ax.yaxis.label.get_position()[1])
    if r.xlabel is not None:
        ax.xaxis.set_label_coords(ax.xaxis.label.get_position()[0], -r.xlabel / size[1])


def _in_view(axis: Axis, locs: np.ndarray) -> np.ndarray:
    """Which of ``locs`` the draw shows: inside the view in the axis' scale, with the relative tolerance
    1e-10 of matplotlib's own test (``Axis._update_ticks``)."""
    lo, hi = sorted(axis.get_view_interval())
    a, b = sorted(axis.get_transform().transform(np.array([lo, hi], float)))
    t = axis.get_transform().transform(np.asarray(locs, float))
    tol = (b - a) * 1e-10
    with np.errstate(invalid="ignore"):
        return (a - tol <= t) & (t <= b + tol)


def pin_ticks(fig: Figure) -> None:
    """Fix each axis' ticks to those the draw of ``fig`` shows, with the labels and offset text its
    locators and formatters give: a fixed locator of the visible locations and a fixed formatter of
    their labels (formatted from all the locations, as the draw formats them). The same SVG, from fewer
    tick artists (module docstring). Call it when nothing that moves the ticks changes any more (limits,
    scales, size): just before saving."""
    from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

    for ax in fig.get_axes():
        for axis in (ax.xaxis, ax.yaxis):
            pinned = []
            for ticker, minor in ((axis.major, False), (axis.minor, True)):
                if isinstance(ticker.locator, NullLocator):
                    pinned.append(None)
                    continue
                # the minor locations without those on major ones, as the draw has them
                locs = np.asarray(axis.get_minorticklocs() if minor else axis.get_majorticklocs(), float)
                labels = ticker.formatter.format_ticks(list(locs))
                offset = ticker.formatter.get_offset()
                keep = _in_view(axis, locs)
                pinned.append((locs[keep], [s for s, k in zip(labels, keep, strict=True) if k], offset))
            for pin, minor in zip(pinned, (False, True), strict=True):
                if pin is not None:
                    fixed = FixedFormatter(pin[1])
                    fixed.set_offset_string(pin[2])
                    (axis.set_minor_locator if minor else axis.set_major_locator)(FixedLocator(pin[0]))
                    (axis.set_minor_formatter if minor else axis.set_major_formatter)(fixed)
            # the minor locations are those left beside the major ones already
            axis.remove_overlapping_locs = False


def lay_out(
    fig: Figure,
    axes: np.ndarray | Sequence[Sequence[Axes]],
    bars: Sequence[Bar] = (),
    title: str | None = None,
    title_size: float = 10.0,
    gap: float = 2 * PAD,
) -> list[Colorbar]:
    """Place ``axes`` (a 2-D array, rows top down) on ``fig`` with the room their decorations need,
    the colorbars ``bars`` right of their columns and ``title`` above all; returns the colorbars.
    ``gap`` [in]: between the decorations of neighbouring axes (more than constrained layout's for a
    stack of panels that share their time axis, which would otherwise touch).

    Call it once everything that takes room (tick formatters, limits, labels, titles) is set.

    The text is measured as the SVG will draw it, at the 72 dpi it is saved at, by the renderer that
    draws it (svg_backend.py: measured here, the draw finds it measured)."""
    from sensorless.reports.svg_backend import measuring_renderer

    dpi = fig.dpi
    fig.dpi = 72  # as when the figure is saved as SVG: text extents in points
    try:
        return _lay_out(fig, axes, bars, title, title_size, gap, measuring_renderer(fig))
    finally:
        fig.dpi = dpi


def _lay_out(
    fig: Figure,
    axes: np.ndarray | Sequence[Sequence[Axes]],
    bars: Sequence[Bar],
    title: str | None,
    title_size: float,
    gap: float,
    renderer: RendererBase,
) -> list[Colorbar]:
    grid = np.asarray(axes, dtype=object)
    grid = grid.reshape(1, -1) if grid.ndim == 1 else grid
    n_r, n_c = grid.shape
    W, H = (float(v) for v in fig.get_size_inches())
    metrics = _Metrics(renderer)
    head = 0.0
    if title:
        sup = fig.suptitle(title, fontsize=title_size, y=1 - PAD / H, va="top")
        head = sup.get_window_extent(renderer).height / fig.dpi + PAD
    first = grid[0, 0].get_position()
    w, h = first.width * W, first.height * H  # the axes' size as made: tick counts depend on it
    caxes: list[Axes] = []
    colorbars: list[Colorbar] = []
    for _ in range(3):  # again with the sizes found until they stay: tick labels change with the size
        size = (w, h)
        rooms = [[room(ax, metrics, size) for ax in row] for row in grid]
        top = [max(r.top for r in row) for row in rooms]
        bottom = [max(r.bottom for r in row) for row in rooms]
        left = [max(rooms[i][c].left for i in range(n_r)) for c in range(n_c)]
        right = [max(rooms[i][c].right for i in range(n_r)) for c in range(n_c)]
        h = (H - head - sum(top) - sum(bottom) - 2 * PAD - gap * (n_r - 1)) / n_r
        y1 = [0.0] * n_r  # each row's top edge [in from the bottom]
        edge = H - head - PAD
        for i in range(n_r):
            y1[i] = edge - top[i]
            edge = y1[i] - h - bottom[i] - gap
        # the colorbars: their height is their rows', their room right of them their own tick labels'
        block = [0.0] * n_c  # [in] right of a column's axes: colorbar and its labels (without the gap)
        spans = []
        for k, b in enumerate(bars):
            rows = range(n_r)[b.rows]
            height = y1[rows[0]] - (y1[rows[-1]] - h)
            width = height / b.aspect
            if len(caxes) <= k:
                caxes.append(fig.add_axes((0.0, (y1[rows[-1]] - h) / H, width / W, height / H)))
                colorbars.append(fig.colorbar(b.mappable, cax=caxes[k], label=b.label))
            spans.append((y1[rows[-1]] - h, height, width))
            r = room(caxes[k], metrics, (width, height))
            block[b.col] = max(block[b.col], width + r.right)
        has_bar = [any(b.col == c for b in bars) for c in range(n_c)]
        free = W - sum(left) - sum(right) - sum(block) - 2 * PAD - gap * (n_c - 1)
        w = free / (n_c + BAR_PAD * sum(has_bar))
        x0 = [0.0] * n_c
        edge = PAD
        for c in range(n_c):
            x0[c] = edge + left[c]
            edge = x0[c] + w + right[c] + (BAR_PAD * w + block[c] if has_bar[c] else 0.0) + gap
        for i in range(n_r):
            for c in range(n_c):
                grid[i, c].set_position((x0[c] / W, (y1[i] - h) / H, w / W, h / H))
        for k, b in enumerate(bars):
            y0, height, width = spans[k]
            x = x0[b.col] + w + right[b.col] + BAR_PAD * w
            caxes[k].set_position((x / W, y0 / H, width / W, height / H))
        if abs(w - size[0]) < 1e-3 and abs(h - size[1]) < 1e-3:
            break
    else:
        rooms = [[room(ax, metrics, (w, h)) for ax in row] for row in grid]
    for i in range(n_r):
        for c in range(n_c):
            _pin_labels(grid[i, c], rooms[i][c], (w, h))
    for k, cax in enumerate(caxes):
        _, height, width = spans[k]
        _pin_labels(cax, room(cax, metrics, (width, height)), (width, height))
    return colorbars
