"""reports/figure_layout.py: the fixed layout leaves every decoration inside the figure, apart from the
others, and each axis label outside its tick labels, as matplotlib itself measures them after a draw;
pinned ticks draw the very SVG matplotlib's own locators and formatters draw."""

import io

import numpy as np
import pytest
from sensorless.reports.document import pyplot
from sensorless.reports.figure_layout import Bar, lay_out, pin_ticks

TOL = 1.0  # [px] rounding of text extents


def _boxes(fig):
    fig.canvas.draw()  # matplotlib's own layout of every text, on the final positions
    r = fig.canvas.get_renderer()
    return r, [(ax, ax.get_tightbbox(r)) for ax in fig.axes]


def _tick_labels(axis, r, k):
    """Extents of the tick labels drawn on ``axis`` (either side; ``k``: 0 for x, 1 for y)."""
    labels = [lab for t in axis.get_major_ticks() for lab in (t.label1, t.label2) if lab.get_visible()]
    ext = [lab.get_window_extent(r) for lab in labels]
    lo, hi = sorted(axis.axes.bbox.get_points()[:, k])
    return [b for b in ext if b.width > 0 and lo - TOL <= b.get_points()[:, k].mean() <= hi + TOL]


def _check(fig):
    r, boxes = _boxes(fig)
    W, H = fig.bbox.width, fig.bbox.height
    for ax, bb in boxes:
        assert bb.x0 >= -TOL and bb.y0 >= -TOL and bb.x1 <= W + TOL and bb.y1 <= H + TOL, (ax, bb)
    for i, (a, ba) in enumerate(boxes):
        for b, bb in boxes[i + 1 :]:
            inter = min(ba.x1, bb.x1) - max(ba.x0, bb.x0), min(ba.y1, bb.y1) - max(ba.y0, bb.y0)
            assert min(inter) <= TOL, (a, b, ba, bb)
    title = fig.get_suptitle() and fig._suptitle.get_window_extent(r)
    for ax, bb in boxes:
        if title:
            assert bb.y1 <= title.y0 + TOL, (ax, bb, title)
        y_ticks = _tick_labels(ax.yaxis, r, 1)
        label = ax.yaxis.label.get_window_extent(r)
        if ax.yaxis.label.get_text() and y_ticks:
            if ax.yaxis.get_label_position() == "left":
                assert label.x1 <= min(b.x0 for b in y_ticks) + TOL, ax
            else:
                assert label.x0 >= max(b.x1 for b in y_ticks) - TOL, ax
        x_ticks = _tick_labels(ax.xaxis, r, 0)
        if ax.xaxis.label.get_text() and x_ticks:
            assert ax.xaxis.label.get_window_extent(r).y1 <= min(b.y0 for b in x_ticks) + TOL, ax


@pytest.fixture(scope="module")
def plt():
    return pyplot()


def test_a_grid_with_colorbars_and_wide_tick_labels(plt):
    fig, axes = plt.subplots(2, 2, figsize=(8, 6))
    for k, ax in enumerate(axes.ravel()):
        sc = ax.scatter([0, 1e4 * (k + 1)], [-2e4, 3e-3 * 10**k], c=[0, 1])
        ax.set_xlabel("Real axis (1/s)")
        ax.set_ylabel(r"$\hat\omega_\mathrm{m}$ (p.u.)")
        ax.set_title(f"panel {k}: a title of some length", fontsize=9)
    bars = [Bar(sc, 0, slice(0, 1), "per cell"), Bar(sc, 1, slice(0, 2), "spanning (p.u.)", aspect=40)]
    lay_out(fig, axes, bars, "a figure title")
    _check(fig)
    plt.close(fig)


def test_stacked_panels_sharing_the_time_axis_and_a_log_axis(plt):
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(6.4, 6.5))
    t = np.linspace(0, 2, 50)
    axes[0].plot(t, 1e5 * np.sin(t))  # an offset text ("1e5") above the axes
    axes[1].semilogy(t, np.exp(10 * t))
    axes[2].plot(t, t, label="x")
    axes[2].set_xlim(0, 2)
    for ax in axes:
        ax.set_ylabel("y label")
    axes[-1].set_xlabel("time (s)")
    lay_out(fig, axes[:, None], title="traces", title_size=9, gap=0.15)
    _check(fig)
    plt.close(fig)


def _stack(plt, pin):
    """Panels sharing x, an offset text, a log axis with minor ticks and labels, a colorbar: saved as
    SVG, with or without the ticks pinned; and the number of tick artists made."""
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(6.4, 6.5))
    t = np.linspace(0.013, 2.07, 50)
    axes[0].plot(t, 1e5 + 3 * np.sin(t), label=r"$\hat\omega$")  # offset text "+1e5"
    axes[0].legend()
    axes[1].semilogy(t, np.exp(3 * t))  # minor ticks with labels inside one decade's span
    sc = axes[2].scatter(t, -t, c=t)
    axes[2].set_xlim(0.013, 2.07)
    fig.colorbar(sc, ax=axes[2], label="c")
    axes[-1].set_xlabel("time (s)")
    fig.set_layout_engine(None)
    if pin:
        pin_ticks(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    ticks = sum(len(a.majorTicks) + len(a.minorTicks) for ax in fig.axes for a in (ax.xaxis, ax.yaxis))
    plt.close(fig)
    return buf.getvalue(), ticks


def test_pinned_ticks_draw_the_same_svg_from_fewer_ticks(plt):
    (free, n_free), (pinned, n_pinned) = _stack(plt, False), _stack(plt, True)
    assert b"xtick_1" in free and b"ytick" in free
    assert pinned == free
    assert n_pinned < n_free  # those outside the view are never made
