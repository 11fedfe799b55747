"""An axis' ticks drawn as a few artists: all grid lines one path, all tick marks one line of markers.

matplotlib draws every tick as a :class:`~matplotlib.axis.Tick` of five artists (two tick marks, a grid
line, two labels), made for each location at the draw (each ~1 ms of CPU with the copy of the first
tick's properties), each drawn on its own, and measures every label once more to place the offset
text. In a report figure that was more than half of the SVG's CPU. :func:`flatten_ticks` (document.py
``svg_uri``, after figure_layout.py ``pin_ticks`` has fixed the locations and labels the draw shows)
replaces an axis' ticks by one :class:`FlatTicks` artist that draws, with the first tick's own
artists (its style: size, width, colours, pads, fonts, clip) at every location, the grid lines as one
path, each side's tick marks as one line of markers and each label in turn. What a person sees is the
same; the SVG holds the same strokes and glyphs, grouped differently (one path of grid lines per axis,
one group of tick marks per side).

An axis keeps matplotlib's own ticks where the draw would still measure its tick labels to place
something: its offset text ("1e4": placed below the labels) or an axis label that figure_layout.py
``lay_out`` did not pin.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.artist import Artist, allow_rasterization
from matplotlib.colors import to_rgba

if TYPE_CHECKING:  # typed by name only
    from matplotlib.axis import Axis, Tick
    from matplotlib.backend_bases import RendererBase
    from matplotlib.figure import Figure
    from matplotlib.text import Text


class FlatTicks(Artist):
    """The ticks of one axis (major, then minor): ``groups`` of (a tick to draw with, its locations,
    their labels)."""

    def __init__(self, axis: Axis, groups: list[tuple[Tick, np.ndarray, list[str]]]) -> None:
        super().__init__()
        self._axis = axis
        self._groups = groups
        self.set_zorder(axis.get_zorder())  # drawn where the axis draws its ticks

    @allow_rasterization  # as every artist's draw: a rasterized artist before it ends its image here
    def draw(self, renderer: RendererBase) -> None:
        if not (self.get_visible() and self._axis.get_visible()):
            return
        vertical = self._axis.axis_name == "y"
        renderer.open_group(f"{self._axis.axis_name}ticks", gid=self.get_gid())
        for tick, locs, labels in self._groups:
            if not tick.get_visible() or not locs.size:
                continue
            n = locs.size
            grid = tick.gridline
            if grid.get_visible():  # each location's line from one side of the axes to the other
                along = np.column_stack((locs, locs, np.full(n, np.nan))).ravel()
                across = np.tile([0.0, 1.0, np.nan], n)
                grid.set_data((across, along) if vertical else (along, across))
                grid.draw(renderer)
            for mark, side in ((tick.tick1line, 0.0), (tick.tick2line, 1.0)):
                if mark.get_visible():
                    at = np.full(n, side)
                    mark.set_data((at, locs) if vertical else (locs, at))
                    mark.draw(renderer)
            for label in (tick.label1, tick.label2):
                if label.get_visible():
                    _draw_labels(label, locs, labels, vertical, renderer)
        renderer.close_group(f"{self._axis.axis_name}ticks")
        self.stale = False


def _draw_labels(
    label: Text, locs: np.ndarray, texts: list[str], vertical: bool, renderer: RendererBase
) -> None:
    """Each of ``texts`` at its location in ``label``'s style: what ``Text.draw`` does for each (its
    group, its layout, ``draw_text`` of each line), with what is the same for all done once: the
    positions (one transform), the graphics context (colour, alpha, clip). Labels with a box, path
    effects, TeX, wrapping or rasterized are drawn by ``Text.draw``."""
    plain = (
        not (label.get_bbox_patch() or label.get_path_effects() or label.get_usetex() or label.get_wrap())
        and not label.get_rasterized()
    )
    if not plain:
        for loc, text in zip(locs, texts, strict=True):
            (label.set_y if vertical else label.set_x)(loc)
            label.set_text(text)
            label.draw(renderer)
        return
    x0, y0 = label.get_unitless_position()
    xy = np.column_stack((np.full(locs.size, x0), locs) if vertical else (locs, np.full(locs.size, y0)))
    at = label.get_transform().transform(xy)
    canvas_h = renderer.get_canvas_width_height()[1]
    gc = renderer.new_gc()
    gc.set_foreground(to_rgba(label.get_color()), isRGBA=True)
    gc.set_alpha(label.get_alpha())
    gc.set_url(label.get_url())
    gc.set_antialiased(label.get_antialiased())
    gc.set_snap(label.get_snap())
    label._set_gc_clip(gc)
    angle = label.get_rotation()
    for text, (px, py) in zip(texts, at, strict=True):
        if not text or not (np.isfinite(px) and np.isfinite(py)):
            continue  # Text.draw draws nothing there
        label.set_text(text)
        renderer.open_group("text", label.get_gid())
        _, lines, _ = label._get_layout(renderer)
        for item in lines:  # (line, extents, (x, y)); matplotlib < 3.10: (line, extents, x, y)
            line, (x, y) = item[0], item[-1] if len(item) == 3 else item[-2:]
            x, y = x + px, y + py
            if renderer.flipy():
                y = canvas_h - y
            clean, ismath = label._preprocess_math(line)
            mtext = label if len(lines) == 1 else None
            renderer.draw_text(gc, x, y, clean, label.get_fontproperties(), angle, ismath=ismath, mtext=mtext)
        renderer.close_group("text")
    gc.restore()


def _flat(axis: Axis) -> list[tuple[Tick, np.ndarray, list[str]]] | None:
    """What :class:`FlatTicks` draws for ``axis`` (its pinned locators and formatters), or None where
    the axis keeps its own ticks (module docstring)."""
    from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

    if axis.major.formatter.get_offset() or (
        getattr(axis, "_autolabelpos", True) and axis.label.get_visible() and axis.label.get_text()
    ):
        return None
    groups = []
    for ticker, ticks in ((axis.major, axis.majorTicks), (axis.minor, axis.minorTicks)):
        if isinstance(ticker.locator, NullLocator):
            continue
        if not (isinstance(ticker.locator, FixedLocator) and isinstance(ticker.formatter, FixedFormatter)):
            return None  # not pinned (figure_layout.py pin_ticks): leave it to matplotlib
        locs = np.asarray(ticker.locator(), float)
        groups.append((ticks[0], locs, ticker.formatter.format_ticks(list(locs))))
    return groups


def flatten_ticks(fig: Figure) -> None:
    """Draw each axis' ticks of ``fig`` as a :class:`FlatTicks` (module docstring). Call it after
    figure_layout.py ``pin_ticks``, just before saving."""
    from matplotlib.axis import Ticker
    from matplotlib.ticker import NullFormatter, NullLocator

    found = []
    for ax in fig.get_axes():
        for axis in (ax.xaxis, ax.yaxis):
            groups = _flat(axis)
            if groups:
                found.append((ax, axis, groups))
    # all found before any axis changes: axes that share an axis share its locators
    for ax, axis, groups in found:
        flat = FlatTicks(axis, groups)
        ax.add_artist(flat)
        flat.set_clip_path(None)  # add_artist clips to the axes; each tick artist keeps its own clip
        # no ticks of its own, on tickers of its own: an axis shared with one that keeps its ticks
        # (module docstring) shares their Ticker objects
        axis.major, axis.minor = Ticker(), Ticker()
        for set_locator, set_formatter in (
            (axis.set_major_locator, axis.set_major_formatter),
            (axis.set_minor_locator, axis.set_minor_formatter),
        ):
            set_locator(NullLocator())
            set_formatter(NullFormatter())
