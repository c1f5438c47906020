"""Which pixels of a photo's mask to believe: the uncertainty band, the frame's border, unseen pixels.

A real mask is not a clean 0/1 image: its edges are soft (blurred or
resampled), JPEG compression rings around them, the subject runs off the
frame, and an undistorted photo leaves pixels unseen (``View.valid``). The
two readers of a mask agree on where it can be trusted:

- a pixel is *uncertain* (:func:`uncertain`) if its value lies in the band
  ``band[0] <= m < band[1]`` and it is not at the mask's edge (no 4-neighbour
  on the other side of 0.5): blur and ringing. At the edge a value in the
  band is the edge's sub-pixel position (an antialiased edge's partial
  coverage) and is believed;
- the visual hull (:func:`mi_loop.fitting.hull.carve`) takes a vote from
  every pixel, :func:`mask_votes`: none from an uncertain pixel, else
  foreground at ``m >= 0.5`` and background below;
- the image loss (:class:`mi_loop.render.images.ImageRenderer`) weights each
  pixel by :func:`pixel_weights`: 0 on uncertain pixels, 0 on foreground
  within ``border`` pixels of the frame or of unseen pixels (the subject
  continues past them, so a render that stops there is not wrong), ``valid``
  elsewhere, else exactly 1.

The band, :data:`MASK_BAND` = (0.2, 0.8), holds what compression does to a
binary mask: saved as JPEG at quality 60 it rings by up to about 0.2 (in the
tests), into the band only next to its edge; at quality 10 by up to 0.5, and
off the edge too. A binary or antialiased mask (a synthetic capture,
:func:`~mi_loop.render.captures.render_views`) has no uncertain pixel: the hull
reads it at 0.5 as before, and inside the frame it gets no loss weights at all
(None), so its fit is unchanged. NumPy only.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from mi_loop.errors import fail

__all__ = ["FRAME_BORDER", "MASK_BAND", "check_band", "mask_votes", "pixel_weights", "uncertain"]

#: Mask values ``band[0] <= m < band[1]`` off the mask's edge are uncertain: no vote, no weight.
MASK_BAND = (0.2, 0.8)
#: Pixels from the frame's edge (or from an unseen pixel) within which foreground says nothing about the outline.
FRAME_BORDER = 2


def check_band(band, func: str) -> tuple[float, float]:
    """Return ``band`` as two floats ``0 < lo <= 0.5 <= hi <= 1``, refusing anything else.

    Parameters
    ----------
    band : (float, float)
        Uncertainty band of mask values.
    func : str
        The public function receiving it, for the message.

    Returns
    -------
    (float, float)

    Raises
    ------
    ValueError
        ``func(): expected a mask band (lo, hi) with 0 < lo <= 0.5 <= hi <= 1, got ...``.
    """
    try:
        lo, hi = (float(b) for b in band)
    except (TypeError, ValueError):
        fail(func, "a mask band (lo, hi) with 0 < lo <= 0.5 <= hi <= 1", repr(band))
    if not 0 < lo <= 0.5 <= hi <= 1:
        fail(func, "a mask band (lo, hi) with 0 < lo <= 0.5 <= hi <= 1", repr(band))
    return lo, hi


def _edge(fg: np.ndarray) -> np.ndarray:
    """Pixels with a 4-neighbour on the other side of the 0.5 crossing."""
    edge = np.zeros_like(fg)
    rows, cols = fg[1:] != fg[:-1], fg[:, 1:] != fg[:, :-1]
    edge[1:] |= rows
    edge[:-1] |= rows
    edge[:, 1:] |= cols
    edge[:, :-1] |= cols
    return edge


def uncertain(mask, band=MASK_BAND) -> np.ndarray:
    """Pixels whose mask value says nothing: in the band, and not at the mask's edge (module docstring).

    Parameters
    ----------
    mask : (h, w) float NumPy array
        Foreground in [0, 1].
    band : (float, float)
        Uncertainty band ``(lo, hi)``, :data:`MASK_BAND` by default.

    Returns
    -------
    (h, w) bool NumPy array
        ``lo <= mask < hi`` and no 4-neighbour on the other side of 0.5.

    Examples
    --------
    >>> ramp = np.array([[0.0, 0.1, 0.3, 0.4, 0.6, 0.7, 0.9, 1.0]])     # a soft edge
    >>> uncertain(ramp).astype(int).tolist()                           # 0.4 and 0.6 place it
    [[0, 0, 1, 0, 0, 1, 0, 0]]
    """
    lo, hi = check_band(band, "uncertain")
    mask = np.asarray(mask)
    return (mask >= lo) & (mask < hi) & ~_edge(mask >= 0.5)


def mask_votes(mask, band=MASK_BAND) -> np.ndarray:
    """Each pixel's vote on whether the subject is there: 1 foreground, -1 background, 0 uncertain.

    Parameters
    ----------
    mask : (h, w) float NumPy array
        Foreground in [0, 1].
    band : (float, float)
        Uncertainty band ``(lo, hi)``, :data:`MASK_BAND` by default.

    Returns
    -------
    (h, w) int8 NumPy array
        0 on :func:`uncertain` pixels, else 1 where ``mask >= 0.5`` and -1 below.

    Examples
    --------
    >>> mask_votes(np.array([[0.0, 0.1, 0.3, 0.4, 0.6, 0.7, 0.9, 1.0]])).tolist()
    [[-1, -1, 0, -1, 1, 0, 1, 1]]
    """
    lo, hi = check_band(band, "mask_votes")
    mask = np.asarray(mask)
    vote = np.where(mask >= 0.5, 1, -1).astype(np.int8)
    vote[uncertain(mask, (lo, hi))] = 0
    return vote


def pixel_weights(mask, valid=None, *, band=MASK_BAND, border: int = FRAME_BORDER):
    """Per-pixel weights of the image loss from a mask (module docstring); None where all would be 1.

    Parameters
    ----------
    mask : (h, w) float NumPy array
        Foreground in [0, 1].
    valid : (h, w) float NumPy array, optional
        The share of each pixel the photo saw (``View.valid``); None: all of every pixel.
    band : (float, float)
        Uncertainty band, :data:`MASK_BAND` by default.
    border : int
        Width in pixels of the frame's border (and of the border of unseen
        pixels, ``valid < 0.5``) on which foreground pixels get weight 0; 0: none.

    Returns
    -------
    (h, w) float32 NumPy array or None
        In [0, 1]: 0 on :func:`uncertain` pixels and on the border's
        foreground, ``valid`` elsewhere (1 without it); None when every
        weight is exactly 1.

    Raises
    ------
    ValueError
        A bad band, a negative border, ``valid`` of another shape than ``mask``.

    Examples
    --------
    >>> m = np.zeros((8, 10)); m[2:6, 3:7] = 1.0
    >>> pixel_weights(m) is None                                  # binary, inside the frame
    True
    >>> m[3, 4] = 0.5                                             # in the band, off the edge
    >>> w = pixel_weights(m); float(w[3, 4]), float(w.sum())
    (0.0, 79.0)
    >>> m[2:6, 0:3] = 1.0                                         # the subject runs off the frame
    >>> int((pixel_weights(m) == 0).sum())                        # 4 x 2 on the border, and the 0.5
    9
    """
    lo, hi = check_band(band, "pixel_weights")
    if isinstance(border, bool) or not isinstance(border, (int, np.integer)) or border < 0:
        fail("pixel_weights", "an integer border >= 0", border)
    mask = np.asarray(mask, dtype=np.float32)
    fg = mask >= 0.5
    w = np.where(uncertain(mask, (lo, hi)), 0.0, 1.0).astype(np.float32)
    unseen = np.zeros(mask.shape, dtype=bool)
    if valid is not None:
        valid = np.asarray(valid, dtype=np.float32)
        if valid.shape != mask.shape:
            fail("pixel_weights", f"valid of the mask's shape {mask.shape}", f"shape {valid.shape}")
        w *= valid
        unseen = valid < 0.5
    if border:
        outside = np.pad(unseen, border, constant_values=True)
        near = ndimage.binary_dilation(outside, np.ones((3, 3), bool), iterations=border)[border:-border,
                                                                                       border:-border]
        w[near & fg] = 0.0
    return None if (w == 1).all() else w
