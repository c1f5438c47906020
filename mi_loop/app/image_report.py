"""Pictures of an image fit: the loss per iteration by stage, and photos next to renders (no file I/O)."""
from __future__ import annotations

import numpy as np

__all__ = ["image_loss_plot", "progress_grid"]


def image_loss_plot(history: list) -> np.ndarray:
    """The image loss per iteration (log scale), one colour per stage, with a running mean.

    Parameters
    ----------
    history : list of dict
        :attr:`mi_loop.fitting.images.ImageFitResult.history` (``stage``, ``loss`` per iteration).

    Returns
    -------
    (h, w, 3) uint8 NumPy array
    """
    from mi_loop.app.report import agg_figure, figure_pixels

    fig = agg_figure(6.4, 4.0)
    ax = fig.add_subplot()
    loss = np.array([h["loss"] for h in history])
    stage = np.array([h["stage"] for h in history])
    it = np.arange(1, len(loss) + 1)
    for k in np.unique(stage):
        sel = stage == k
        ax.semilogy(it[sel], loss[sel], ".", markersize=2, alpha=0.5, label=f"stage {k}")
    window = max(1, len(loss) // 40)
    running = np.convolve(loss, np.ones(window) / window, mode="valid")
    ax.semilogy(it[window - 1:], running, color="black", linewidth=1.2, label=f"running mean ({window})")
    ax.set_xlabel("iteration")
    ax.set_ylabel("mean L1 of the rendered views (linear RGB)")
    ax.set_title("image loss per iteration (stages: exact Loop refinements)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return figure_pixels(fig)


def progress_grid(evaluation: dict, shown) -> np.ndarray:
    """Rows: the photos (over the lighting), the start's renders, the fit's renders; one column per view.

    Parameters
    ----------
    evaluation : dict
        ``targets`` (list of (h, w, 3) linear images) and ``start``/``end`` dicts with ``images``.
    shown : list of int
        The views' indices (used for nothing but their count here).

    Returns
    -------
    (3 h, len(shown) w, 3) float32 NumPy array
        sRGB values in [0, 1].
    """
    from mi_loop.io.srgb import linear_to_srgb

    rows = [evaluation["targets"], evaluation["start"]["images"], evaluation["end"]["images"]]
    return np.concatenate([np.concatenate([linear_to_srgb(np.asarray(im)[..., :3]) for im in row], axis=1)
                           for row in rows], axis=0)
