"""The report figures' SVG backend: matplotlib's own, with each string measured and shaped once a process.

matplotlib's SVG renderer draws text as paths: every string is measured (FreeType shaping of the whole
string) to lay it out, then shaped again to place its glyphs, and a mathtext string is parsed (pyparsing,
~10 ms) for each new renderer. figure_layout.py ``lay_out`` measured every tick label, axis label and
title once more on an Agg renderer (hinted, at the figure's dpi), parsing the trace figures' mathtext
labels again. Here one :class:`TextCache` (matplotlib's ``TextToPath`` remembering what it measured and
shaped: the same numbers, computed once) serves :func:`measuring_renderer`, on which ``lay_out``
measures, and the renderer that writes the SVG: the draw finds every string already measured, a
repeated one (tick labels, the same axis label on each panel) already shaped, each mathtext string
parsed once.

Used through ``savefig(..., backend=BACKEND)`` (document.py ``svg_uri``): the SVG is matplotlib's
``print_svg`` with :class:`Renderer` in place of ``RendererSVG`` (each font's height metrics read once)
and :class:`Mixed` in place of ``MixedModeRenderer`` (one raster buffer for all rasterized artists),
written to a string and encoded once; its bytes are those matplotlib writes.
"""

from __future__ import annotations

import functools
import io
import sys
from collections import OrderedDict
from collections.abc import Iterable
from typing import IO, TYPE_CHECKING

import numpy as np
from matplotlib import cbook
from matplotlib.backends.backend_agg import RendererAgg
from matplotlib.backends.backend_mixed import MixedModeRenderer
from matplotlib.backends.backend_svg import FigureCanvasSVG, RendererSVG
from matplotlib.textpath import TextToPath

if TYPE_CHECKING:  # typed by name only
    from matplotlib.figure import Figure
    from matplotlib.font_manager import FontProperties
    from matplotlib.ft2font import FT2Font

BACKEND = "module://sensorless.reports.svg_backend"
# the matplotlib versions this module and figure_ticks.py were checked on (they reach into matplotlib's
# private renderer, text and axis internals): on any other, the report draws with matplotlib as it comes
TESTED = ((3, 11),)
Glyph = tuple[str, float, float, float]  # a glyph's SVG name, x, y, scale (matplotlib's TextToPath)
Outlines = OrderedDict[str, tuple[np.ndarray, np.ndarray]]  # glyph name -> its outline (vertices, codes)
Features = tuple[str, ...] | None  # OpenType features of a text (matplotlib >= 3.10)
Language = str | tuple[tuple[str, int, int], ...] | None
CACHED = 4096  # strings kept (a report's figures draw a few hundred distinct ones)


class TextCache(TextToPath):
    """``TextToPath`` that keeps each string's extents and glyph layout (they depend on the string and
    the font only): what matplotlib computes, once."""

    def __init__(self) -> None:
        super().__init__()
        self._extents = functools.lru_cache(CACHED)(self._measured)
        self._laid_out = functools.lru_cache(CACHED)(self._shaped)
        self._outlines: Outlines = OrderedDict()  # every glyph's, by its SVG name

    def _measured(self, s: str, prop: FontProperties, ismath: bool | str) -> tuple[float, float, float]:
        return super().get_text_width_height_descent(s, prop, ismath)

    def get_text_width_height_descent(
        self, s: str, prop: FontProperties, ismath: bool | str
    ) -> tuple[float, float, float]:
        return self._extents(s, prop.copy(), ismath)  # a copy: the caller may change its own later

    def _shaped(self, font: FT2Font, s: str, features: Features, language: Language) -> tuple[Glyph, ...]:
        kw = {} if features is None and language is None else {"features": features, "language": language}
        # the outlines of glyphs not met before only (matplotlib's glyph_map: outlines by glyph name)
        info, new, _ = super().get_glyphs_with_font(font, s, self._outlines, True, **kw)
        self._outlines.update(new)
        return tuple(info)

    def get_glyphs_with_font(
        self,
        font: FT2Font,
        s: str,
        glyph_map: Outlines | None = None,
        return_new_glyphs_only: bool = False,
        *,
        features: Features = None,
        language: Language = None,
    ) -> tuple[list[Glyph], Outlines, list[object]]:
        """As matplotlib's: the glyphs of ``s`` (name, x, y, scale) and the outlines of those not in
        ``glyph_map`` (only those, or ``glyph_map`` with them added)."""
        info = self._laid_out(font, s, features, language)
        glyph_map = OrderedDict() if glyph_map is None else glyph_map
        new = OrderedDict() if return_new_glyphs_only else glyph_map
        for name, *_ in info:
            if name not in glyph_map:
                new[name] = self._outlines[name]
        return list(info), new, []


TEXT = TextCache()  # this process's


@functools.cache
def supported() -> bool:
    """Whether this matplotlib is one of :data:`TESTED` (the fast path: this backend, flat ticks)."""
    import matplotlib

    return tuple(int(p) for p in matplotlib.__version__.split(".")[:2]) in TESTED


def warm(texts: Iterable[str]) -> None:
    """Parse the mathtext among ``texts`` here (svg_render.py ``svg_later``, before it forks): a figure
    child then finds it parsed (matplotlib parses a mathtext string at one size for every size it is
    drawn at), not each child again (~10 ms a string; a trace figure's labels are mathtext)."""
    from matplotlib.font_manager import FontProperties

    if not supported():
        return
    for s in texts:
        if cbook.is_math_text(s):
            TEXT.get_text_width_height_descent(s, FontProperties(), ismath=True)


@functools.lru_cache(CACHED)
def _font_heights(prop: FontProperties) -> tuple[float, float, float] | tuple[None, None, None]:
    """(ascent, descent, line gap) [px at 72 dpi] of the font of ``prop``, from its OS/2 or hhea table:
    matplotlib's ``Text._get_layout`` at the figure's 72 dpi (the same expressions), for the hook it
    asks a renderer first. It looked the font up and read two of its tables for every text laid out
    (~1000 a report's figures), where a figure uses a few fonts."""
    from matplotlib.font_manager import fontManager, get_font

    font = get_font(fontManager._find_fonts_by_props(prop))
    dpi = 72
    for table_name, linegap_key, ascent_key, descent_key in (
        ("OS/2", "sTypoLineGap", "sTypoAscender", "sTypoDescender"),
        ("hhea", "lineGap", "ascent", "descent"),
    ):
        table = font.get_sfnt_table(table_name)
        if table is None:
            continue
        fontsize = prop.get_size_in_points()
        units_per_em = font.get_sfnt_table("head")["unitsPerEm"]
        scale = 1 / units_per_em * fontsize * dpi / 72
        return table[ascent_key] * scale, -table[descent_key] * scale, table[linegap_key] * scale
    return None, None, None  # matplotlib measures "lp" instead


class Renderer(RendererSVG):
    """matplotlib's SVG renderer on this process's :data:`TEXT`, with each font's height metrics read
    once (:func:`_font_heights`). It measures and draws at 72 dpi only: the figure's dpi whenever it is
    in use (``print_svg`` and figure_layout.py ``lay_out`` set it)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)
        self._text2path = TEXT

    def _get_font_height_metrics(
        self, prop: FontProperties
    ) -> tuple[float, float, float] | tuple[None, None, None]:
        # matplotlib's Text._get_layout asks a renderer with this (private) method before reading the
        # font's tables itself (its PDF and PS renderers have it)
        return _font_heights(prop.copy())  # a copy: the caller may change its own later


def measuring_renderer(fig: Figure) -> RendererSVG:
    """A renderer that measures text as the SVG's will (``fig.dpi`` must be 72, as when it is saved),
    writing nothing anyone reads (matplotlib's own where this matplotlib is not :func:`supported`)."""
    width, height = fig.get_size_inches()
    return (Renderer if supported() else RendererSVG)(width * 72, height * 72, io.StringIO())


def _painted(img: np.ndarray) -> tuple[slice, slice]:
    """The rows and columns of an RGBA buffer's pixels with alpha > 0 (matplotlib's
    ``cbook._get_nonzero_slices`` of its alpha channel): the alpha of each pixel read as the top byte
    of its 32-bit word, the columns searched in the painted rows only (a pole map's scatter covers a
    quarter of the figure-sized buffer)."""
    packed = img.view(np.uint32).reshape(img.shape[:2])
    on = packed >= 1 << 24 if sys.byteorder == "little" else (packed & 0xFF) != 0
    rows = np.flatnonzero(on.any(axis=1))
    if not rows.size:
        return slice(0, 0), slice(0, 0)
    cols = np.flatnonzero(on[rows[0] : rows[-1] + 1].any(axis=0))
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1)


class Mixed(MixedModeRenderer):
    """matplotlib's mixed-mode renderer, finding a rasterized artist's pixels in the figure-sized buffer
    faster (:func:`_painted`; the same image), and drawing every rasterized artist of the figure on one
    such buffer, cleared after each: matplotlib makes a new one for each, and a pole map rasterizes ten
    (its scatters and colorbars) on 7 MB buffers, new pages to fault in each time."""

    _spare: RendererAgg | None = None  # the buffer of the last rasterized artist, cleared

    def start_rasterizing(self) -> None:
        spare = self._spare
        if self._bbox_inches_restore or spare is None:  # the first, or not the report's case
            return super().start_rasterizing()
        # matplotlib's MixedModeRenderer.start_rasterizing, on the cleared buffer: as a new one is
        self.figure.dpi = self.dpi
        self._spare = None
        self._raster_renderer = self._renderer = spare

    def stop_rasterizing(self) -> None:
        raster = self._raster_renderer
        if self._bbox_inches_restore or raster is None:  # not the report's case: matplotlib's own
            return super().stop_rasterizing()
        # matplotlib's MixedModeRenderer.stop_rasterizing, with _painted
        self._renderer = self._vector_renderer
        height = self._height * self.dpi
        img = np.asarray(raster.buffer_rgba())
        slice_y, slice_x = _painted(img)
        cropped = img[slice_y, slice_x]
        if cropped.size:
            gc = self._renderer.new_gc()
            self._renderer.draw_image(
                gc,
                slice_x.start * self._figdpi / self.dpi,
                (height - slice_y.stop) * self._figdpi / self.dpi,
                cropped[::-1],
            )  # written out (PNG) already: the buffer is free
        raster.clear()  # as RendererAgg makes it: every pixel the clear colour
        self._spare = raster
        self._raster_renderer = None
        self.figure.dpi = self._figdpi


class FigureCanvas(FigureCanvasSVG):
    """matplotlib's SVG canvas drawing with :class:`Renderer`."""

    def print_svg(
        self,
        filename: str | IO[str],
        *,
        bbox_inches_restore: object = None,
        metadata: dict[str, object] | None = None,
        **_applied: object,
    ) -> None:
        # matplotlib's FigureCanvasSVG.print_svg, with Renderer and Mixed in place of RendererSVG and
        # MixedModeRenderer; ``_applied``: what print_figure passes a canvas not of matplotlib's own (dpi,
        # facecolor, edgecolor, orientation), set on the figure already; matplotlib's print_svg takes none.
        # The SVG is written to a string, then to the file at once: matplotlib writes a binary file
        # through a codecs writer, a Python call and an encode for each of the ~5000 pieces of a figure
        with cbook.open_file_cm(filename, "w", encoding="utf-8") as fh:
            text = io.StringIO()
            name = getattr(fh, "name", "")  # the images' file names if not inline, as matplotlib's
            dpi = self.figure.dpi
            self.figure.dpi = 72
            width, height = self.figure.get_size_inches()
            w, h = width * 72, height * 72
            renderer = Mixed(
                self.figure,
                width,
                height,
                dpi,
                Renderer(w, h, text, name if isinstance(name, str) else "", image_dpi=dpi, metadata=metadata),
                bbox_inches_restore=bbox_inches_restore,
            )
            self.figure.draw(renderer)
            renderer.finalize()
            svg = text.getvalue()
            fh.write(svg if cbook.file_requires_unicode(fh) else svg.encode("utf-8"))
