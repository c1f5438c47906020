"""The ARAP weight of a fit to noisy data, chosen on points held out of the fit.

How much to regularise depends on the noise and on the shape at once: a
shape the control mesh resolves easily wants a strong weight on noisy data,
one it only just resolves a weak weight even with more noise (the demo torus
and the noisy bunny range scans, BENCHMARKS.md "Noise-aware defaults").
No rule on the noise level alone gets both, so the weight is measured: a
tenth of the points is held out, the fit runs on the rest for each weight of
:data:`ALPHAS` in increasing order, and the weight whose limit surface lies
closest to the held-out points (mean exact point-to-surface distance) wins.
Noise on the held-out points is independent of the fit, so it adds the same
to every candidate and the order follows the distance to the true surface.
The search stops at the first weight that is worse than the one before.
"""
from __future__ import annotations

import numpy as np

__all__ = ["ALPHAS", "HELD_OUT", "MIN_POINTS", "SPLIT_STREAM", "held_out_split", "select_alpha"]

#: Candidate ARAP weights, tried in this order.
ALPHAS = (0.001, 0.01, 0.1, 1.0)
#: Share of the points held out of the candidate fits.
HELD_OUT = 0.1
#: Fewest points for which a selection is made (100 held out).
MIN_POINTS = 1000
#: Second word of the split's seed sequence: a stream of its own.
SPLIT_STREAM = 0x5E1EC7


def held_out_split(n: int, seed: int) -> np.ndarray:
    """A boolean mask of the points to hold out: :data:`HELD_OUT` of ``n``, drawn with ``seed``.

    The draw comes from its own stream (``SeedSequence([seed, SPLIT_STREAM])``),
    not from ``default_rng(seed)``: data drawn with that generator would
    otherwise share its words with the draw. That happened: the NPS
    benchmark's points are area samples drawn with ``default_rng(0)`` (face
    ``i`` where the ``i``-th uniform falls in the cumulative areas), so the
    split from ``default_rng(0)`` held out every sample of a tenth of the
    faces, and every fit to the other nine tenths had a hole to bridge.

    Parameters
    ----------
    n : int
        Number of points.
    seed : int
        The fit's seed.

    Returns
    -------
    (n,) bool NumPy array

    Examples
    --------
    >>> mask = held_out_split(10_000, 0)
    >>> bool(900 < mask.sum() < 1100), bool((mask == held_out_split(10_000, 0)).all())
    (True, True)
    """
    return np.random.default_rng(np.random.SeedSequence([int(seed), SPLIT_STREAM])).random(n) < HELD_OUT


def select_alpha(fit_with, held_out_error, alphas=ALPHAS, progress=None):
    """Fit with each weight in turn and keep the one closest to the held-out points.

    Parameters
    ----------
    fit_with : callable
        ``fit_with(alpha, progress)`` runs the fit on the kept points and
        returns ``(V, history, converged)``.
    held_out_error : callable
        ``held_out_error(V)``: the mean distance of the held-out points to the
        limit surface of control points ``V``.
    alphas : sequence of float, optional
        Candidates in increasing order.
    progress : callable, optional
        ``progress(i, n, energy)`` over all candidates together.

    Returns
    -------
    alpha : float
        The chosen weight.
    fitted : tuple
        Its ``(V, history, converged)``.
    tried : dict
        ``alphas`` and ``held_out_mean``: every candidate that ran, in order.
    """
    tried = {"alphas": [], "held_out_mean": []}
    best = None
    for k, alpha in enumerate(alphas):
        step = None if progress is None else (
            lambda i, n, E, k=k: progress(k * n + i, len(alphas) * n, E))
        fitted = fit_with(alpha, step)
        error = float(held_out_error(fitted[0]))
        tried["alphas"].append(float(alpha))
        tried["held_out_mean"].append(error)
        if best is not None and error >= best[2]:       # every earlier candidate was better than the one before
            break
        best = (float(alpha), fitted, error)
    return best[0], best[1], tried
