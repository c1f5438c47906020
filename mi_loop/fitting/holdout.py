"""Held-out photos: which views an image fit leaves out, and how a render of the fit scores on them.

A fit to photos is judged on photos it never saw (``mi-loop fit-images
--holdout K``): :func:`split_views` leaves out every ``K``-th photo, the views
``i`` with ``i % K == K - 1`` (``K - 1``, ``2 K - 1``, ...: the first photo is
always fitted); after the fit each held-out view is rendered from the fitted
surface and compared with its photo by :func:`silhouette_iou` (the outline)
and :func:`masked_psnr` (the colour inside the photo's mask). NumPy only, no
file I/O.
"""
from __future__ import annotations

import numpy as np

from mi_loop.errors import fail

__all__ = ["masked_psnr", "silhouette_iou", "split_views"]


def split_views(n_views: int, k: int) -> tuple[list[int], list[int]]:
    """Split ``n_views`` photos into those to fit and every ``k``-th one, held out.

    Parameters
    ----------
    n_views : int
        Photos in the capture, >= 0.
    k : int
        0: hold none out; else ``2 <= k <= n_views``, and at least two photos stay to fit.

    Returns
    -------
    fitted, held : list of int
        Indices of the photos to fit and of those held out (``i % k == k - 1``), ascending.

    Raises
    ------
    ValueError
        ``k`` negative or 1 (nothing would be left to fit), larger than ``n_views``
        (nothing held out), or leaving fewer than two photos to fit.

    Examples
    --------
    >>> split_views(7, 3)
    ([0, 1, 3, 4, 6], [2, 5])
    >>> split_views(4, 0)
    ([0, 1, 2, 3], [])
    """
    func = "split_views"
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 0 or k == 1:
        fail(func, "a holdout K of 0 (off) or an integer >= 2 (K = 1 would hold out every photo)", k)
    if k == 0:
        return list(range(n_views)), []
    if k > n_views:
        fail(func, f"a holdout K of at most the {n_views} photos (a larger K holds none out)", int(k))
    held = list(range(k - 1, n_views, k))
    if n_views - len(held) < 2:
        fail(func, f"a holdout K that leaves at least two of the {n_views} photos to fit",
             f"K = {int(k)}, which leaves {n_views - len(held)}")
    return [i for i in range(n_views) if i % k != k - 1], held


def _seen(shape, valid, func: str) -> np.ndarray:
    """The pixels to score: ``valid >= 0.5``, or all of them."""
    if valid is None:
        return np.ones(shape, bool)
    valid = np.asarray(valid)
    if valid.shape != shape:
        fail(func, f"valid of the masks' shape {shape}", f"shape {valid.shape}")
    return valid >= 0.5


def silhouette_iou(rendered, photo, valid=None) -> float:
    """Return the intersection over union of a rendered silhouette and a photo's mask.

    Parameters
    ----------
    rendered : (h, w) float NumPy array
        The render's coverage (alpha) in [0, 1].
    photo : (h, w) float NumPy array
        The photo's foreground mask in [0, 1].
    valid : (h, w) float NumPy array, optional
        The share of each pixel the photo saw (:attr:`mi_loop.io.View.valid`);
        pixels below 0.5 are left out.

    Returns
    -------
    float
        ``|R & P| / |R | P|`` over the scored pixels, both masks thresholded at
        0.5 (``>= 0.5`` is inside); NaN when neither covers a scored pixel.

    Raises
    ------
    ValueError
        Masks of different shapes, or not 2-D.

    Examples
    --------
    >>> a = np.zeros((4, 4)); a[:2] = 1          # rows 0-1
    >>> b = np.zeros((4, 4)); b[1:3] = 1         # rows 1-2: one shared row of three
    >>> silhouette_iou(a, b)
    0.3333333333333333
    """
    func = "silhouette_iou"
    R, P = np.asarray(rendered), np.asarray(photo)
    if R.ndim != 2 or R.shape != P.shape:
        fail(func, "two masks of one shape (h, w)", f"shapes {R.shape} and {P.shape}")
    seen = _seen(P.shape, valid, func)
    R, P = (R >= 0.5) & seen, (P >= 0.5) & seen
    union = int(np.count_nonzero(R | P))
    return float(np.count_nonzero(R & P) / union) if union else float("nan")


def masked_psnr(rendered, photo, mask, valid=None) -> float:
    """Return the peak signal-to-noise ratio of a render against a photo inside the photo's mask, in dB.

    Parameters
    ----------
    rendered, photo : (h, w, 3) float NumPy arrays
        The images in one encoding (``mi-loop fit-images`` passes sRGB), clipped to [0, 1] here.
    mask : (h, w) float NumPy array
        The photo's foreground mask; pixels ``>= 0.5`` are scored.
    valid : (h, w) float NumPy array, optional
        The share of each pixel the photo saw; pixels below 0.5 are left out.

    Returns
    -------
    float
        ``10 log10(1 / MSE)``, the mean over the scored pixels and the three
        channels; inf for equal images, NaN without a scored pixel.

    Raises
    ------
    ValueError
        Images not of shape (h, w, 3) or not of the mask's (h, w).

    Examples
    --------
    >>> photo = np.zeros((2, 2, 3)); render = photo + 0.1
    >>> round(masked_psnr(render, photo, np.ones((2, 2))), 6)
    20.0
    """
    func = "masked_psnr"
    R, P, M = np.asarray(rendered, float), np.asarray(photo, float), np.asarray(mask)
    if R.shape != P.shape or R.ndim != 3 or R.shape[2] != 3 or M.shape != R.shape[:2]:
        fail(func, "images of shape (h, w, 3) and a mask of shape (h, w)",
             f"shapes {R.shape}, {P.shape} and {M.shape}")
    inside = (M >= 0.5) & _seen(M.shape, valid, func)
    if not inside.any():
        return float("nan")
    mse = float(np.mean((np.clip(R[inside], 0, 1) - np.clip(P[inside], 0, 1)) ** 2))
    return float("inf") if mse == 0 else float(10 * np.log10(1 / mse))
