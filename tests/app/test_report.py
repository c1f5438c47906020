"""Tests of the pictures of a fit (mi_loop.app.report): no pyplot, every term visible, integer frames."""
from __future__ import annotations

import sys

import numpy as np

from mi_loop.app.report import (
    LOSS_TERMS,
    drift_figure,
    figure_pixels,
    loss_figure,
    loss_plot,
)


def history(n=50, cover=True):
    """Energies where the coverage term is almost the whole total (as in real fits)."""
    it = np.arange(n)
    imls = 1e-5 * np.exp(-it / 20)
    cov = (3e-3 * np.exp(-it / 30)) if cover else np.zeros(n)
    arap = np.full(n, 1e-7)
    fold = 1e-6 * np.exp(-it / 10)
    return {"imls": imls.tolist(), "cover": cov.tolist(), "arap": arap.tolist(), "fold": fold.tolist(),
            "total": (imls + cov + arap + fold).tolist()}


def legend(fig):
    return [t.get_text() for t in fig.axes[0].get_legend().get_texts()]


def test_the_legend_lists_the_total_and_every_non_zero_term():
    assert legend(loss_figure(history())) == ["total E", *LOSS_TERMS.values()]
    assert legend(loss_figure(history(cover=False))) == ["total E", LOSS_TERMS["imls"], LOSS_TERMS["arap"],
                                                         LOSS_TERMS["fold"]]
    without_fold = history() | {"fold": [0.0] * 50}                          # the barrier off: no fold line
    assert legend(loss_figure(without_fold)) == ["total E", *list(LOSS_TERMS.values())[:3]]


def test_a_term_that_is_the_whole_total_is_drawn_on_top_of_it():
    """The coverage curve runs on the total (to 0.3 %): it must be drawn above it, and its colour seen."""
    fig = loss_figure(history())
    lines = {line.get_label(): line for line in fig.axes[0].get_lines()}
    total, cover = lines["total E"], lines[LOSS_TERMS["cover"]]
    assert cover.get_zorder() > total.get_zorder()
    assert cover.get_linewidth() < total.get_linewidth()           # the total stays visible around it
    pixels = figure_pixels(fig).astype(float) / 255
    colour = np.array(__import__("matplotlib").colors.to_rgb(cover.get_color()))
    seen = (np.abs(pixels - colour).max(2) < 0.08).sum()
    legend_only = 40 * 2                                            # the legend's sample line is ~40 px long
    assert seen > 5 * legend_only, seen                             # the curve itself shows, not just the legend


def test_loss_plot_is_an_image_and_pyplot_is_not_needed():
    image = loss_plot(history())
    assert image.shape == (400, 640, 3) and image.dtype == np.uint8 and image.std() > 10
    import subprocess

    code = ("import sys\nfrom mi_loop.app.report import loss_plot\n"
            "loss_plot({'total': [1.0, 0.5], 'imls': [1.0, 0.5]})\n"
            "print('matplotlib.pyplot' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


def test_drift_has_integer_frame_ticks():
    fig = drift_figure([0, 1, 2], [1e-3, 2e-3, 1.5e-3], [2e-3, 3e-3, 2.5e-3])
    figure_pixels(fig)                                              # lays the ticks out
    ax = fig.axes[0]
    lo, hi = ax.get_xlim()
    ticks = [t for t in ax.get_xticks() if lo <= t <= hi]
    assert ticks == [0.0, 1.0, 2.0]
