"""Pictures of an image fit: the loss per iteration by stage, and photos next to renders (no file I/O)."""
from __future__ import annotations

import numpy as np

__all__ = ["holdout_grid", "image_loss_plot", "progress_grid"]

#: Most views side by side in :func:`holdout_grid` (more wrap to further rows).
HOLDOUT_COLUMNS = 6


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
    """Rows: the photos (over the lighting), the start's renders, the fit's renders, and (where the evaluation
    has them) the fit's geometry in grey under a side light; one column per view.

    Parameters
    ----------
    evaluation : dict
        ``targets`` (list of (h, w, 3) linear images), ``start``/``end`` dicts with ``images``,
        optionally ``relief`` (list of (h, w, 3) linear images).
    shown : list of int
        The views' indices (used for nothing but their count here).

    Returns
    -------
    (r h, len(shown) w, 3) float32 NumPy array
        sRGB values in [0, 1]; ``r`` is 4 with ``relief``, else 3.
    """
    from mi_loop.io.srgb import linear_to_srgb

    rows = [evaluation["targets"], evaluation["start"]["images"], evaluation["end"]["images"]]
    rows += [evaluation["relief"]] if "relief" in evaluation else []
    return np.concatenate([np.concatenate([linear_to_srgb(np.asarray(im)[..., :3]) for im in row], axis=1)
                           for row in rows], axis=0)


def holdout_grid(photos, renders, columns: int = HOLDOUT_COLUMNS) -> np.ndarray:
    """Held-out photos above renders of the fit from their cameras and the silhouettes' agreement.

    Rows: the photo as taken, the render, and the masks (both thresholded at
    0.5): white where both cover a pixel, red where only the photo's mask does,
    blue where only the render does, black where neither (grey where the photo
    saw nothing, ``valid < 0.5``). One column per view, ``columns`` to a band;
    further views start a band below.

    Parameters
    ----------
    photos, renders : list of mi_loop.io.View
        The held-out views and the renders of the fit from the same cameras (one size).
    columns : int
        Views per band, >= 1.

    Returns
    -------
    (3 h bands, min(n, columns) w, 3) float32 NumPy array
        sRGB values in [0, 1] (empty cells black).
    """
    from mi_loop.io.srgb import linear_to_srgb

    cells = []
    for photo, render in zip(photos, renders):
        p, r = photo.mask >= 0.5, render.mask >= 0.5
        agree = np.zeros(p.shape + (3,), np.float32)
        agree[p & r], agree[p & ~r], agree[~p & r] = 1.0, (1.0, 0.1, 0.1), (0.2, 0.4, 1.0)
        if photo.valid is not None:
            agree[photo.valid < 0.5] = 0.5
        cells.append(np.concatenate([linear_to_srgb(photo.rgb), linear_to_srgb(render.rgb), agree], axis=0))
    columns = min(columns, len(cells))
    blank = np.zeros_like(cells[0])
    cells += [blank] * (-len(cells) % columns)
    bands = [np.concatenate(cells[j:j + columns], axis=1) for j in range(0, len(cells), columns)]
    return np.concatenate(bands, axis=0).astype(np.float32)
