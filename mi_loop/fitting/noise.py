"""The noise level of a point cloud against its spacing, and what the static fit does with it.

The noise is measured against the point spacing, ``ratio = sigma / h``:
``sigma`` from residuals of local quadric fits
(:func:`~mi_loop.mesh.points.noise_level`), ``h`` the median distance from a
point to its 12th nearest neighbour (the IMLS term's own neighbourhood). A
ratio, not sigma alone: the IMLS distance averages the points within about
``h`` of a sample, so noise well below ``h`` averages out there, while noise
comparable to ``h`` (dense, noisy data) is followed unless ARAP holds the
surface. Measured (``bench/bench_noise.py ratios``): meshes sampled without
noise 0.00-0.03, the merged bunny range scans 0.08, the demo torus (Gaussian
noise 0.5 % of the diagonal, 20,000 points) 0.30.

Up to :data:`RATIO_CLEAN` the data counts as clean and the fit runs as it
always did (ARAP weight :data:`ALPHA_CLEAN`, pymeshlab's Poisson settings).
Above it:

- :func:`template_options`: the template's screened Poisson surface screens
  less and averages more points per node, ending at :data:`RATIO_NOISY` as
  plain (unscreened) Poisson with 10 points per node. The template sets the
  shape ARAP keeps: on the demo torus a screened-Poisson template carries the
  noise into the fit (mean distance to the clean torus 5.3e-4 of the
  diagonal at ARAP weight 1, against 3.9e-4 from the smooth template);
- the ARAP weight is chosen on held-out points (:mod:`mi_loop.fitting.selection`).
"""
from __future__ import annotations

import numpy as np

__all__ = ["ALPHA_CLEAN", "RATIO_CLEAN", "RATIO_NOISY", "noise_estimate", "template_options"]

#: ARAP weight for data whose noise is below :data:`RATIO_CLEAN` of the point spacing (closest on the
#: clean benchmarks).
ALPHA_CLEAN = 0.001
#: Noise / spacing ratio up to which data counts as clean (scans of real objects: 0.07-0.08).
RATIO_CLEAN = 0.1
#: Noise / spacing ratio from which the template is plain Poisson.
RATIO_NOISY = 0.3
#: Neighbours of each local quadric fit (:func:`~mi_loop.mesh.points.noise_level`).
QUADRIC_NEIGHBOURS = 24
#: Neighbour whose distance is the point spacing (the IMLS term's ``min_neighbors``).
SPACING_NEIGHBOUR = 12


def noise_estimate(P, *, tree=None, samples: int = 2000) -> dict:
    """Noise level of a point cloud, absolute and against its point spacing.

    Parameters
    ----------
    P : (N, 3) float numpy array
        Points; with 24 or fewer nothing is estimated (zero noise).
    tree : scipy.spatial.cKDTree, optional
        A k-d tree of ``P``, if one exists already.
    samples : int, optional
        Points at which the local fits and spacings are measured (an even subsample).

    Returns
    -------
    dict
        ``sigma`` (noise standard deviation along the normals, units of ``P``),
        ``spacing`` (median distance to the 12th nearest neighbour), ``ratio``
        (``sigma / spacing``) and ``sigma_diagonal`` (``sigma`` over the
        bounding-box diagonal), ``estimated`` (False for too few points).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> P = rng.normal(size=(20000, 3)); P /= np.linalg.norm(P, axis=1, keepdims=True)
    >>> noisy = P * (1 + 0.01 * rng.normal(size=(20000, 1)))          # sigma 0.01, spacing about 0.05
    >>> round(noise_estimate(P)["ratio"], 2), round(noise_estimate(noisy)["ratio"], 1)
    (0.0, 0.2)
    """
    from scipy.spatial import cKDTree

    from mi_loop.mesh.points import noise_level

    P = np.asarray(P, dtype=np.float64)
    if len(P) <= QUADRIC_NEIGHBOURS:
        return {"sigma": 0.0, "spacing": 0.0, "ratio": 0.0, "sigma_diagonal": 0.0, "estimated": False}
    tree = cKDTree(P) if tree is None else tree
    sigma = noise_level(P, QUADRIC_NEIGHBOURS, tree=tree, samples=samples)
    d, _ = tree.query(P[::max(1, len(P) // int(samples))], k=SPACING_NEIGHBOUR + 1, workers=-1)
    spacing = float(np.median(d[:, -1]))
    diagonal = float(np.linalg.norm(np.ptp(P, axis=0)))
    return {"sigma": sigma, "spacing": spacing, "ratio": sigma / spacing if spacing > 0 else 0.0,
            "sigma_diagonal": sigma / diagonal if diagonal > 0 else 0.0, "estimated": True}


def _t(ratio: float) -> float:
    return float(np.clip((ratio - RATIO_CLEAN) / (RATIO_NOISY - RATIO_CLEAN), 0.0, 1.0))


def template_options(ratio: float) -> dict:
    """Screened-Poisson settings of the automatic template for data with noise ``ratio`` times its spacing.

    Parameters
    ----------
    ratio : float
        ``sigma / spacing``, from :func:`noise_estimate`.

    Returns
    -------
    dict
        ``point_weight`` (4, pymeshlab's default, down to 0 linearly) and
        ``samples_per_node`` (1.5 up to 10, log-linearly): keywords of
        :func:`~mi_loop.fitting.template.make_template`.

    Examples
    --------
    >>> template_options(0.05), template_options(0.3)
    ({'point_weight': 4.0, 'samples_per_node': 1.5}, {'point_weight': 0.0, 'samples_per_node': 10.0})
    """
    t = _t(ratio)
    return {"point_weight": float(4.0 * (1.0 - t)), "samples_per_node": float(np.round(1.5 * (10 / 1.5) ** t, 6))}
