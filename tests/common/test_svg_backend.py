"""reports/svg_backend.py: the report's SVG backend writes the bytes matplotlib's own SVG backend writes,
for a figure whose rasterized artists (scatters of different extents and colours in several axes, a
colorbar) it draws one after another on the one cleared raster buffer."""

import io

import numpy as np
import pytest
from sensorless.reports import svg_backend
from sensorless.reports.document import pyplot


def _svg(backend: str | None) -> bytes:
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(6, 5))
    x = np.linspace(0, 1, 300)
    for k, ax in enumerate(axes.ravel()):
        # each scatter covers a different part of its axes: an image cropped from the last one's buffer
        # would show its pixels or be cut to its size
        sc = ax.scatter(
            x**k, np.sin((k + 2) * x), c=x, cmap=("turbo", "viridis")[k % 2], s=4 + 5 * k, rasterized=True
        )
        ax.plot(x, x, lw=0.5)  # vector drawing between the rasterized artists
    fig.colorbar(sc, ax=axes[:, 1]).solids.set_rasterized(True)
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None}, **({"backend": backend} if backend else {}))
    plt.close(fig)
    return buf.getvalue()


@pytest.mark.skipif(not svg_backend.supported(), reason="a matplotlib the backend was not checked on")
def test_rasterized_artists_give_matplotlibs_own_bytes():
    own, ours = _svg(None), _svg(svg_backend.BACKEND)
    assert own.count(b"<image") == 5  # four scatters and the colorbar, each its own image
    assert ours == own


def _text_svg() -> bytes:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1], [0, 1], label="one\ntwo lines")
    ax.legend(fontsize=7)
    ax.set_title("title\nof three\nlines", fontsize=11, fontweight="bold")
    ax.text(0.1, 0.5, "serif,\nitalic", family="serif", style="italic", fontsize=13)
    ax.set_xlabel(r"$\hat\omega$ (rad/s)")
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None}, backend=svg_backend.BACKEND)
    plt.close(fig)
    return buf.getvalue()


@pytest.mark.skipif(not svg_backend.supported(), reason="a matplotlib the backend was not checked on")
def test_font_heights_read_once_lay_out_text_as_matplotlib_does(monkeypatch):
    """Multi-line texts in several fonts and sizes (their line spacing is the font's height metrics)
    are placed where matplotlib places them reading each font's tables for every text."""
    ours = _text_svg()
    monkeypatch.delattr(svg_backend.Renderer, "_get_font_height_metrics")
    assert ours == _text_svg()
