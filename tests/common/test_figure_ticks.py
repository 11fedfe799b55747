"""reports/figure_ticks.py: an axis' ticks drawn as a few artists give the very pixels matplotlib's own
ticks give (grid lines, tick marks on both sides, labels, minor ticks of a log axis, a colorbar, axes
sharing an axis, an axis that keeps its own ticks for its offset text), from fewer tick artists."""

import base64

import numpy as np
import pytest
from sensorless.reports import svg_backend
from sensorless.reports.document import pyplot, svg_uri
from sensorless.reports.figure_layout import lay_out, pin_ticks
from sensorless.reports.figure_ticks import FlatTicks, flatten_ticks


def _pixels(flat: bool) -> tuple[np.ndarray, int, int]:
    """The figure drawn by Agg, with or without flat ticks; the tick objects made and the FlatTicks."""
    plt = pyplot()
    fig, axes = plt.subplots(3, 2, sharex="col", figsize=(8, 6.5))
    t = np.linspace(0.013, 2.07, 50)
    axes[0, 0].plot(t, 1e5 + 3 * np.sin(t), label=r"$\hat\omega$")  # offset text "+1e5": kept as it is
    axes[0, 0].legend(loc="upper right")
    axes[1, 0].semilogy(t, np.exp(3 * t))  # minor ticks with labels inside one decade's span
    axes[1, 0].tick_params(right=True, which="both")  # tick marks on both sides
    sc = axes[2, 0].scatter(t, -t, c=t)
    axes[2, 0].set_xlim(0.013, 2.07)
    for ax in axes[:, 1]:
        ax.plot(t, np.cos(5 * t), "k--")
        ax.grid(True, lw=0.3, color="0.8", ls="--")  # dashes restart at each grid line
    for ax in axes.ravel():
        ax.set_ylabel("y (unit)")
    axes[0, 1].yaxis.set_label_position("right")
    axes[-1, 0].set_xlabel("time (s)")
    from sensorless.reports.figure_layout import Bar

    lay_out(fig, axes, [Bar(sc, 0, slice(2, 3), "c")], title="ticks")
    pin_ticks(fig)
    if flat:
        flatten_ticks(fig)
    fig.canvas.draw()
    pixels = np.asarray(fig.canvas.buffer_rgba()).copy()
    ticks = sum(len(a.majorTicks) + len(a.minorTicks) for ax in fig.axes for a in (ax.xaxis, ax.yaxis))
    n_flat = sum(isinstance(c, FlatTicks) for ax in fig.axes for c in ax.get_children())
    plt.close(fig)
    return pixels, ticks, n_flat


@pytest.mark.skipif(not svg_backend.supported(), reason="a matplotlib the flat ticks were not checked on")
def test_flat_ticks_draw_the_same_pixels_from_fewer_tick_artists():
    (own, n_own, none), (flat, n_flat, flats) = _pixels(False), _pixels(True)
    assert none == 0 and flats >= 12  # every axis but the one with an offset text, and the colorbar's
    assert n_flat < n_own / 2
    diff = np.abs(own.astype(int) - flat.astype(int))
    assert diff.max() <= 1, np.argwhere(diff > 1)[:5]


def test_another_matplotlib_draws_with_matplotlib_as_it_comes(monkeypatch):
    """On a matplotlib outside svg_backend.TESTED the report's figures are matplotlib's own SVG: no flat
    ticks, no cached text (a figure still laid out and written)."""
    plt = pyplot()
    tested = svg_backend.supported()

    def svg(fast: bool) -> bytes:
        monkeypatch.setattr(svg_backend, "supported", lambda: fast)
        fig, ax = plt.subplots(figsize=(3, 2))
        ax.plot([0, 1, 2], [1, 0, 2])
        ax.set_xlabel("speed (p.u.)")
        lay_out(fig, [[ax]])
        return base64.b64decode(svg_uri(fig).split(",", 1)[1])

    plain = svg(False)
    assert plain.startswith(b"<?xml") and b'id="xtick_1"' in plain  # matplotlib's own tick groups
    if tested:  # and on this one, the flat ticks in their place
        assert b'id="xtick_1"' not in svg(True)
